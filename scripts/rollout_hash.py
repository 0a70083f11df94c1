#!/usr/bin/env python
"""Digests of seeded rollouts of every registered environment: observations, rewards, flags and infos, bit for bit.

A refactoring that must not change any output (speed work on the environments, their plumbing or the geometry
helpers) is checked by running this before and after it and comparing the two outputs::

    python scripts/rollout_hash.py > before.json     # on the old code
    python scripts/rollout_hash.py > after.json      # on the new code
    diff before.json after.json && echo identical

Each line is one (id, configuration, seed): a SHA-256 of every observation array (dtype, shape and bytes), reward,
terminated/truncated flag and info value of a rollout of ``--steps`` steps of random actions (a seeded generator,
``scale`` x the action space), resetting whenever an episode ends. The configurations cover the observation and
action types, noise, randomised dynamics, a camera slower than the control, images and reflex stops. Digests
depend on the machine's floating-point libraries: compare runs of one machine.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from typing import Any

import numpy as np

CONFIGS: dict[str, list[dict[str, Any]]] = {
    "FrankaIBVS-v0": [
        {}, dict(observation_type="state"),
        dict(action_type="cartesian_velocity", feature_noise=0.5, joint_noise=1e-3, velocity_noise=1e-3),
        dict(link_mass_range=(0.8, 1.2), friction_scale_range=(0.5, 1.5), payload_mass_range=(0, 0.5),
             control_period=0.04, camera_period=0.03),
        dict(action_type="torque", time_limit=1.0), dict(observation_type="features+image", time_limit=1.0),
        dict(limit_rate=False, robot="fr3")],
    "FrankaPBVS-v0": [{}, dict(observation_type="state", payload_mass_range=(0, 0.5), payload_declared=False)],
    "FrankaTorqueTracking-v0": [{}, dict(friction_scale_range=(0.5, 1.5), link_mass_range=(0.8, 1.2)),
                                dict(clip_actions=True, time_limit=1.0, scale=1.0)],
    "FrankaVisualTorque-v0": [{}, dict(observation_type="state"), dict(feature_noise=0.5, link_mass_range=(0.8, 1.2))],
    "FrankaIBVSEyeToHand-v0": [{}, dict(action_type="torque", robot="fr3")],
    "FrankaPBVSEyeToHand-v0": [{}],
}


def _update(h: Any, x: Any) -> None:
    if isinstance(x, dict):
        for k in sorted(x):
            h.update(k.encode())
            _update(h, x[k])
    elif isinstance(x, np.ndarray):
        h.update(f"{x.dtype}{x.shape}".encode())
        h.update(np.ascontiguousarray(x).tobytes())
    elif isinstance(x, (list, tuple)):
        for v in x:
            _update(h, v)
    elif isinstance(x, (float, np.floating)):
        h.update(np.float64(x).tobytes())
    else:
        h.update(repr(x).encode())


def rollout_digest(env_id: str, config: dict[str, Any], seed: int, steps: int) -> str:
    """SHA-256 (hex, 16 digits) of one seeded rollout of ``steps`` steps (see the module docstring)."""
    import gymnasium as gym

    import franka_vs_gym  # noqa: F401

    kw = dict(config)
    scale = kw.pop("scale", 0.3)
    env = gym.make(env_id, **kw)
    h = hashlib.sha256()
    rng = np.random.default_rng(seed)
    try:
        _update(h, env.reset(seed=seed))
        space = env.action_space
        for _ in range(steps):
            a = (rng.uniform(space.low, space.high) * scale).astype(space.dtype)
            out = env.step(a)
            _update(h, out)
            if out[2] or out[3]:
                _update(h, env.reset())
    finally:
        env.close()
    return h.hexdigest()[:16]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=400, help="steps per rollout (default 400)")
    ap.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1 per configuration (default 3)")
    args = ap.parse_args()
    if args.steps < 1 or args.seeds < 1:
        raise SystemExit("--steps and --seeds must be >= 1")
    out = {}
    for env_id, configs in CONFIGS.items():
        for i, cfg in enumerate(configs):
            for seed in range(args.seeds):
                out[f"{env_id}/{i}/{seed}"] = rollout_digest(env_id, cfg, seed, args.steps)
                print(f"  {env_id} config {i} seed {seed}", file=sys.stderr, flush=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
