"""Speed of the environments, measured as ratios within one run (``scripts/bench.py`` calls :func:`bench`).

For each environment (features observations; state for the torque-tracking task) we time ``n_steps`` environment
steps of a zero action made with ``gymnasium.make``, then, on the same MuJoCo model and data, the raw
``mujoco.mj_step`` calls those steps contain (``n_substeps`` per step). The ratio env / raw is the price of
everything that is not MuJoCo's integrator: the robot's friction and control hooks, observations, reward, checks
and Gymnasium's wrappers. Target: <= 1.5. Resets (inverse kinematics of the start pose) are timed separately.
"""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np


def _time_env(env_id: str, n_steps: int, seed: int, kwargs: dict[str, Any]) -> dict[str, Any]:
    env = gym.make(env_id, **kwargs)
    u = env.unwrapped
    action = np.zeros(env.action_space.shape, dtype=env.action_space.dtype)
    env.reset(seed=seed)
    env.step(action)  # first step runs Gymnasium's passive checker: leave it out of the timing
    resets, reset_time, step_time = 0, 0.0, 0.0
    for _ in range(n_steps):
        t0 = time.perf_counter()
        _, _, term, trunc, _ = env.step(action)
        step_time += time.perf_counter() - t0
        if term or trunc:
            t0 = time.perf_counter()
            env.reset()
            reset_time += time.perf_counter() - t0
            resets += 1
    # raw physics on the same model and data, as many mj_step calls as the env steps contained
    m, d = u.world.model, u.world.data
    n_raw = n_steps * u.n_substeps
    step = mujoco.mj_step
    t0 = time.perf_counter()
    for _ in range(n_raw):
        step(m, d)
    raw_time = time.perf_counter() - t0
    # FrankaSim's own stepping (the per-physics-step friction/control hooks) for reference
    t0 = time.perf_counter()
    u.world.step(n_raw)
    world_time = time.perf_counter() - t0
    env.close()
    us = step_time / n_steps * 1e6
    raw_us = raw_time / n_steps * 1e6
    return {
        "steps_per_s": n_steps / step_time,
        "us_per_step": us,
        "substeps": u.n_substeps,
        "control_period_s": u.control_period,
        "mj_step_us": raw_time / n_raw * 1e6,
        "physics_us_per_step": raw_us,
        "robot_step_us_per_step": world_time / n_steps * 1e6,
        "ratio": us / raw_us,
        "overhead_pct": 100.0 * (us / raw_us - 1.0),
        "reset_ms": 1e3 * reset_time / resets if resets else float("nan"),
        "resets": resets,
    }


def _time_async(env_id: str, n_envs: int, n_steps: int, seed: int, kwargs: dict[str, Any]) -> dict[str, Any]:
    import franka_vs_gym  # noqa: F401

    fns = [lambda: gym.make(env_id, **kwargs) for _ in range(n_envs)]
    venv = gym.vector.AsyncVectorEnv(fns)
    try:
        venv.reset(seed=seed)
        actions = np.zeros(venv.action_space.shape, dtype=venv.action_space.dtype)
        venv.step(actions)
        t0 = time.perf_counter()
        for _ in range(n_steps):
            venv.step(actions)
        dt = time.perf_counter() - t0
    finally:
        venv.close()
    return {"env_id": env_id, "n_envs": n_envs, "vector_steps_per_s": n_steps / dt,
            "env_steps_per_s": n_envs * n_steps / dt}


def bench(env_ids: list[str] | None = None, n_steps: int = 300, seed: int = 0, async_envs: int = 2,
          async_steps: int = 300, async_env_id: str = "FrankaIBVS-v0", verbose: bool = False) -> dict[str, Any]:
    """Environment steps/s next to the raw ``mj_step`` cost of the same steps, and AsyncVectorEnv throughput.

    Returns ``{"envs": {env_id: {"steps_per_s", "us_per_step", "substeps", "mj_step_us", "physics_us_per_step",
    "robot_step_us_per_step", "ratio", "overhead_pct", "reset_ms", ...}}, "async": {...}}``; ``ratio`` is the env
    step time over the raw physics time of its substeps (1.5 = 50 % overhead). ``async_envs=0`` skips the vector
    test.
    """
    import franka_vs_gym  # noqa: F401
    from franka_vs_gym.envs.registration import ENVS

    if n_steps < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    ids = list(ENVS) if env_ids is None else list(env_ids)
    out: dict[str, Any] = {"envs": {}}
    for env_id in ids:
        if env_id not in ENVS:
            raise ValueError(f"unknown environment id {env_id!r} (have {list(ENVS)})")
        kwargs = {} if env_id == "FrankaTorqueTracking-v0" else {"observation_type": "features"}
        r = _time_env(env_id, n_steps, seed, kwargs)
        out["envs"][env_id] = r
        if verbose:
            print(f"{env_id:26s} {r['steps_per_s']:8.0f} steps/s  {r['us_per_step']:7.1f} us/step  "
                  f"{r['substeps']:3d} x mj_step = {r['physics_us_per_step']:7.1f} us  ratio {r['ratio']:.2f}",
                  flush=True)
    if async_envs:
        out["async"] = _time_async(async_env_id, async_envs, async_steps, seed, {"observation_type": "features"})
        if verbose:
            a = out["async"]
            print(f"AsyncVectorEnv({async_envs}) {async_env_id}: {a['env_steps_per_s']:.0f} env steps/s", flush=True)
    return out
