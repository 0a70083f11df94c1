#!/usr/bin/env python
"""How episodes of a uniformly random policy end, per environment and robot: by a reflex, or by the time limit
or the task's own conditions (success, tag lost, a joint-limit or contact failure of the task).

"before" is the robot's old interface (actions in physical units over the robot's whole limits, no rate
limiter: ``action_scale="physical", limit_rate=False``); "after" the defaults (normalized actions with the task's
documented scale, libfranka's rate limiter on, the joint-limit guard on for joint velocity actions); "unguarded"
the defaults without the joint-limit guard (``joint_limit_guard=False``). Besides the reflex share, the share of
episodes that end at a joint limit (the robot's position reflex, or the task's joint-limit condition that ends an
episode just before the reflex would). Each episode is reset with seed ``seed + i`` and the actions drawn
from the action space seeded the same way, so runs are repeatable.

    python scripts/random_policy.py [--episodes 100] [--robots fer,fr3] [--envs ID,...]
                                    [--settings before,unguarded,after] [--json OUT]
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
import time
from pathlib import Path

import gymnasium as gym

import franka_vs_gym  # noqa: F401  (registers the ids)
from franka_vs_gym.envs.registration import ENVS
from franka_vs_gym.io import atomic_write

REFLEX_NAMES = ("joint_position_limits_violation", "joint_velocity_violation", "tau_J_range_violation",
                "controller_torque_discontinuity", "joint_motion_generator_velocity_discontinuity",
                "joint_motion_generator_acceleration_discontinuity")
SETTINGS = {"before": {"action_scale": "physical", "limit_rate": False}, "unguarded": {"joint_limit_guard": False},
            "after": {}}


def run(env_id: str, robot: str, setting: str, episodes: int, seed: int) -> dict:
    """Run ``episodes`` random episodes; the count of each way they ended."""
    env = gym.make(env_id, robot=robot, **SETTINGS[setting])
    ends: collections.Counter = collections.Counter()
    steps = 0
    try:
        for i in range(episodes):
            env.reset(seed=seed + i)
            env.action_space.seed(seed + i)
            while True:
                _, _, term, trunc, info = env.step(env.action_space.sample())
                steps += 1
                if term or trunc:
                    break
            failure = info.get("failure")
            if info.get("reflex") is not None or (failure and failure.split(",")[0] in REFLEX_NAMES):
                ends["reflex: " + failure] += 1
            elif failure:
                ends["task: " + failure.split(":")[0]] += 1
            elif info.get("is_success"):
                ends["success"] += 1
            else:
                ends["time limit"] += 1
    finally:
        env.close()
    reflex = sum(v for k, v in ends.items() if k.startswith("reflex"))
    at_limit = sum(v for k, v in ends.items() if k in ("reflex: joint_position_limits_violation", "task: joint limit"))
    return {"env": env_id, "robot": robot, "setting": setting, "episodes": episodes, "steps": steps,
            "reflex_share": reflex / episodes, "joint_limit_share": at_limit / episodes, "ends": dict(ends)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=100, help="episodes per env, robot and setting (default 100)")
    ap.add_argument("--robots", default="fer,fr3")
    ap.add_argument("--envs", default=",".join(ENVS), help="env ids (default: all)")
    ap.add_argument("--settings", default="before,after", help="of " + ",".join(SETTINGS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", default=None, help="write the rows to this JSON file (must not exist)")
    args = ap.parse_args()
    if args.episodes < 1:
        ap.error("--episodes must be >= 1")
    bad_settings = [x for x in args.settings.split(",") if x not in SETTINGS]
    if bad_settings:
        ap.error(f"--settings: unknown {bad_settings} (have {list(SETTINGS)})")
    if args.json and Path(args.json).exists():  # checked before the long run, not after it
        ap.error(f"--json {args.json} exists; choose another file name")
    rows = []
    print(f"{'env':26s} {'robot':5s} {'setting':9s} {'reflex':>7s} {'at limit':>8s}  ends", flush=True)
    for env_id in args.envs.split(","):
        for robot in args.robots.split(","):
            for setting in args.settings.split(","):
                t = time.perf_counter()
                r = run(env_id, robot, setting, args.episodes, args.seed)
                r["seconds"] = round(time.perf_counter() - t, 1)
                rows.append(r)
                ends = ", ".join(f"{k} {v}" for k, v in sorted(r["ends"].items(), key=lambda kv: -kv[1]))
                print(f"{env_id:26s} {robot:5s} {setting:9s} {100 * r['reflex_share']:6.1f}% "
                      f"{100 * r['joint_limit_share']:7.1f}%  {ends}", flush=True)
    if args.json:
        atomic_write(args.json, json.dumps(rows, indent=2))
    bad = [r for r in rows if r["setting"] == "after" and max(r["reflex_share"], r["joint_limit_share"]) > 0.05]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
