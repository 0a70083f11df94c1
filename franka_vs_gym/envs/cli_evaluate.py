"""``franka-vs evaluate``: run a scripted policy or a trained agent on an environment and print its scores.

Policies:
  ``ibvs`` / ``pbvs``           franka_vs_gym.policies.IBVSPolicy / PBVSPolicy (visual-servoing envs;
                                joint_velocity actions, or cartesian_velocity with
                                --env-kwargs '{"action_type": "cartesian_velocity"}')
  ``computed-torque`` / ``impedance``   franka_vs_gym.policies torque policies (FrankaTorqueTracking-v0)
  ``zero``                      a zero action (a reference: what doing nothing scores)
  ``ibvs_ppo``, ...            a shipped agent, one for every env and robot (franka_vs_gym.policies.shipped_agents():
                                e.g. ibvs_ppo, ibvs_pixels, pbvs_ppo_fr3, torque_tracking_fer, visual_torque_fr3;
                                needs the [rl] extra); its env id and env kwargs (e.g. observation_type
                                "image" at 64x48 for ibvs_pixels) come from its JSON sidecar
  ``path/to/agent.zip``         a stable-baselines3 agent saved by baselines/train_sb3.py (with its .json)
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from franka_vs_gym.errors import UserError

SCRIPTED = ("ibvs", "pbvs", "computed-torque", "impedance", "zero")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("policy", help=f"one of {', '.join(SCRIPTED)}, a shipped agent (e.g. ibvs_ppo, "
                        "pbvs_ppo_fr3, torque_tracking_fer: the names in franka_vs_gym/policies/agents), or the "
                        "path of an agent .zip")
    parser.add_argument("--env", default=None, help="environment id (default: the agent's, or FrankaIBVS-v0 for "
                        "ibvs/pbvs/zero, FrankaTorqueTracking-v0 for the torque policies)")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0, help="episode i uses seed + i")
    parser.add_argument("--env-kwargs", default="{}", help="JSON object of gymnasium.make keyword arguments")
    parser.add_argument("--json", default=None, help="also write the summary to this JSON file")
    parser.add_argument("--force", action="store_true", help="overwrite the --json file if it exists")
    parser.add_argument("--quiet", action="store_true", help="no per-episode lines")
    parser.add_argument("--robot", default=None, help="the simulated arm (fer or fr3); the same as --env-kwargs "
                        "'{\"robot\": ...}'")
    parser.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                        help="spread the episodes over a Ray cluster at ADDRESS ('auto', 'ray://host:10001'), or a "
                        "local Ray instance when no address is given (needs the [scale] extra); same table")
    parser.add_argument("--ray-cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")


def _scripted(name: str, env_kwargs: dict[str, Any]) -> tuple[Any, str, dict[str, Any]]:
    from franka_vs_gym import policies

    if name in ("ibvs", "pbvs"):
        cls = policies.IBVSPolicy if name == "ibvs" else policies.PBVSPolicy
        kw = {"action_type": "joint_velocity", "observation_type": "features"} | env_kwargs
        if kw["action_type"] not in ("joint_velocity", "cartesian_velocity"):
            raise ValueError(f"the {name.upper()} policy commands joint_velocity or cartesian_velocity actions, "
                             f"not {kw['action_type']!r}")
        pkw: dict[str, Any] = {"action_type": kw["action_type"], "model": kw.get("model"), "robot": kw.get("robot")}
        if name == "ibvs" and "tag_size" in kw:
            pkw["tag_size"] = kw["tag_size"]
        return cls(**pkw), "FrankaIBVS-v0" if name == "ibvs" else "FrankaPBVS-v0", kw
    cls = policies.ComputedTorquePolicy if name == "computed-torque" else policies.JointImpedancePolicy
    policy = cls(env_kwargs.get("model"), robot=env_kwargs.get("robot"))
    return policy, "FrankaTorqueTracking-v0", {"action_type": "torque"} | env_kwargs


def _zero_policy(env_id: str, env_kwargs: dict[str, Any]):
    import gymnasium as gym
    import numpy as np

    env = gym.make(env_id, **env_kwargs)
    shape, dtype = env.action_space.shape, env.action_space.dtype
    env.close()
    return lambda obs: np.zeros(shape, dtype=dtype)


def check_env_kwargs(env_id: str, kwargs: dict[str, Any]) -> None:
    """Refuse (one line) an unknown environment id or a keyword its constructor does not take."""
    import inspect

    import gymnasium as gym

    import franka_vs_gym.envs  # noqa: F401  (registers the environments)

    try:
        spec = gym.spec(env_id)
    except gym.error.Error as e:
        raise UserError(f"unknown environment {env_id!r} ({' '.join(str(e).split())})") from None
    ep = spec.entry_point
    if isinstance(ep, str):
        mod, _, attr = ep.partition(":")
        import importlib

        ep = getattr(importlib.import_module(mod), attr)
    known: set[str] = set()
    for cls in (ep.__mro__ if inspect.isclass(ep) else ()):
        init = cls.__dict__.get("__init__")
        if init is None:
            continue
        params = inspect.signature(init).parameters.values()
        known |= {p.name for p in params if p.kind in (p.KEYWORD_ONLY, p.POSITIONAL_OR_KEYWORD) and p.name != "self"}
        if not any(p.kind == p.VAR_KEYWORD for p in params):
            break
    if not known:
        return
    unknown = sorted(set(kwargs) - known - {"render_mode"})
    if unknown:
        raise UserError(f"--env-kwargs: {env_id} takes no keyword {', '.join(map(repr, unknown))} (it takes "
                        f"{', '.join(sorted(known))})")


def resolve_policy(name: str, env: str | None, env_kwargs: dict[str, Any]) -> tuple[Any, str, dict[str, Any]]:
    """(policy, env id, env kwargs) for a policy name of the command line (see the module docstring)."""
    from franka_vs_gym.policies import load_agent, shipped_agents

    if (name.endswith(".zip") or Path(name).suffix == ".zip" or Path(name + ".zip").is_file()
            or name in shipped_agents()):
        policy = load_agent(name)
        env_id = env or policy.env_id
        defaults = getattr(policy, "env_defaults", {"observation_type": "features", "action_type": "joint_velocity"})
        kw = defaults | policy.env_kwargs | env_kwargs
    elif name == "zero":
        env_id = env or "FrankaIBVS-v0"
        kw = env_kwargs
        check_env_kwargs(env_id, kw)
        policy = _zero_policy(env_id, kw)
    elif name in SCRIPTED:
        policy, default_env, kw = _scripted(name, env_kwargs)
        env_id = env or default_env
    else:
        raise ValueError(f"unknown policy {name!r}: use one of {', '.join(SCRIPTED + tuple(shipped_agents()))} "
                         "or an agent .zip path")
    check_env_kwargs(env_id, kw)  # one line for an unknown environment or keyword, before anything runs
    return policy, env_id, kw


def _policy_only(name: str, env: str | None, env_kwargs: dict[str, Any]) -> Any:
    """The policy alone (built in each Ray task: policies need not be picklable)."""
    import franka_vs_gym  # noqa: F401

    return resolve_policy(name, env, env_kwargs)[0]


def main(args: argparse.Namespace) -> int:
    import franka_vs_gym
    from franka_vs_gym.io import atomic_write, check_output

    if args.seed < 0:
        raise UserError(f"--seed must be >= 0 (episode i uses seed + i), got {args.seed}")
    try:
        env_kwargs = json.loads(args.env_kwargs)
    except json.JSONDecodeError as e:
        raise ValueError(f"--env-kwargs is not valid JSON: {e}") from None
    if not isinstance(env_kwargs, dict):
        raise ValueError("--env-kwargs must be a JSON object")
    if getattr(args, "robot", None) is not None:
        from franka_vs_gym.model.description import robot_description

        env_kwargs["robot"] = robot_description(args.robot).name
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if args.json:
        check_output(args.json, args.force, what="--json file")
    name = args.policy
    policy, env_id, kw = resolve_policy(name, args.env, env_kwargs)
    if args.ray is not None:
        import functools

        from franka_vs_gym.scale import evaluate_distributed

        factory = functools.partial(_policy_only, name, args.env, env_kwargs)
        r = evaluate_distributed(factory, env_id, args.episodes, args.seed, env_kwargs=kw,
                                 address=args.ray or None, num_cpus=args.ray_cpus, progress=not args.quiet)
    else:
        r = franka_vs_gym.evaluate(policy, env_id, args.episodes, args.seed, env_kwargs=kw,
                                   progress=not args.quiet)
    t = r["mean_time_to_converge"]
    print(f"{name} on {env_id} ({args.episodes} episodes, seeds {args.seed}..{args.seed + args.episodes - 1}): "
          f"success rate {r['success_rate']:.2f}, mean time to converge "
          f"{'n/a' if math.isnan(t) else f'{t:.2f} s'}, median final error {r['median_final_error']:.4g}, "
          f"mean return {r['mean_return']:.3f}, failures {r['failures'] or 'none'}")
    if args.json:
        def clean(x: Any) -> Any:
            if isinstance(x, float) and not math.isfinite(x):
                return None
            if isinstance(x, dict):
                return {k: clean(v) for k, v in x.items()}
            if isinstance(x, list):
                return [clean(v) for v in x]
            return x

        p = atomic_write(args.json, json.dumps(clean({"policy": name, "env_id": env_id, "env_kwargs": kw, **r}),
                                               indent=2), force=args.force, what="--json file")
        print(f"wrote {p}")
    return 0
