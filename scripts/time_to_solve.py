#!/usr/bin/env python
"""Time to solve: wall-clock time from nothing to an agent with >= 95 % success on 100 held-out episodes.

    python scripts/time_to_solve.py                        # FrankaIBVS-v0, features agent (PPO, native vector env)
    python scripts/time_to_solve.py --task panda-reach     # panda-gym's PandaReach-v3, its documented SB3 recipe
    python scripts/time_to_solve.py --task ibvs-pixels     # FrankaIBVS-v0 from the camera image (DAgger student)
    python scripts/time_to_solve.py --json result.json     # also write the result (the file must not exist)

"From nothing" starts the clock before the environments and the untrained model are made; it stops when a periodic
evaluation on the held-out episodes (seeds ``--eval-seed`` ... ``--eval-seed + 99``; training draws its episodes
from seeds 0 ... n_envs - 1) first reaches ``--goal``. The evaluations are inside the clock (their share is
reported). Also reported: the process CPU time (all threads), which is what the wall time would be on a quiet
machine with as many cores as threads used, and the machine's load (``os.getloadavg``) at start and end: on a
shared machine the wall time says more about the neighbours than about the method.

FrankaIBVS-v0 (``--task ibvs``): PPO on ``franka_vs_gym.envs.sb3.make_agent_vec_env`` (``n_envs`` robots on one
``mujoco.batch``, the flat servo vector observation and [-1, 1] actions of ``baselines/train_sb3.py``), evaluated
with all 100 held-out episodes stepped together on the same native vector env (the same episodes, bit for bit, as
``franka_vs_gym.evaluate`` with that seed, which confirms the final agent). PandaReach-v3 (``--task panda-reach``,
needs ``pip install panda-gym``): panda-gym's documented recipe, ``DDPG(policy="MultiInputPolicy", env)`` with
SB3's defaults and a 30 000-step budget (panda-gym's "Train with stable-baselines3" page), evaluated on 100
episodes the same way (deterministic actions, success = ``info["is_success"]`` at the episode's end).
FrankaIBVS-v0 from the camera image (``--task ibvs-pixels``): ``baselines/train_pixels.py``'s DAgger student
(64x48 image, q, dq; the scripted IBVS teacher's actions as labels), its held-out evaluation every 3 iterations
(12 000 labelled states with 16 robots), stopped at ``--goal``; the saved agent is confirmed with
``franka_vs_gym.evaluate``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

# The IBVS features agent's recipe (stated in the output).
IBVS_PPO = {"learning_rate": 1e-3, "n_steps": 64, "batch_size": 256, "n_epochs": 10, "gamma": 0.98,
            "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0,
            "policy_kwargs": {"net_arch": [64, 64], "log_std_init": -1.0}}


_EVAL_ENVS: dict[tuple, Any] = {}


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


class Clock:
    def __init__(self) -> None:
        self.t0, self.c0 = time.perf_counter(), time.process_time()
        self.eval_wall = 0.0

    def wall(self) -> float:
        return time.perf_counter() - self.t0

    def cpu(self) -> float:
        return time.process_time() - self.c0


def evaluate_ibvs(model: Any, env_id: str, n: int, seed: int, action_scale: float, env_kwargs: dict[str, Any],
                  nthread: int | None) -> dict[str, float]:
    """The first episode of each of n robots (robot i reset with seed + i, as franka_vs_gym.evaluate's episode i),
    deterministic actions, all stepped together: (success rate, mean time to converge of the successes)."""
    from franka_vs_gym.envs.sb3 import make_agent_vec_env

    key = (env_id, n, action_scale, nthread, json.dumps(env_kwargs, sort_keys=True))
    if key not in _EVAL_ENVS:  # made once (its robots' models), reset with the held-out seeds at each evaluation
        _EVAL_ENVS[key] = make_agent_vec_env(env_id, n, action_scale, nthread=nthread, **env_kwargs)
    venv = _EVAL_ENVS[key]
    venv.seed(seed)
    obs = venv.reset()
    done = np.zeros(n, dtype=bool)
    success = np.zeros(n, dtype=bool)
    t_conv = np.full(n, np.nan)
    length = np.zeros(n, dtype=np.int64)
    while not done.all():
        a, _ = model.predict(obs, deterministic=True)
        obs, _, dones, infos = venv.step(a)
        length[~done] += 1
        for i in np.flatnonzero(dones & ~done):
            done[i] = True
            success[i] = bool(infos[i].get("is_success", False))
            t_conv[i] = infos[i].get("time", np.nan) if success[i] else np.nan
    return {"success_rate": float(success.mean()),
            "mean_time_to_converge": float(np.nanmean(t_conv)) if success.any() else float("nan"),
            "episodes": [{"success": bool(a), "length": int(b), "time_to_converge": float(c)}
                         for a, b, c in zip(success, length, t_conv, strict=True)]}


def run_ibvs(args: argparse.Namespace) -> dict[str, Any]:
    import torch

    torch.set_num_threads(args.threads)
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecMonitor

    import franka_vs_gym
    from franka_vs_gym.envs.sb3 import make_agent_vec_env
    from franka_vs_gym.envs.wrappers import AgentPolicy

    env_kwargs: dict[str, Any] = {}
    clock = Clock()
    env = VecMonitor(make_agent_vec_env(args.env_id, args.n_envs, args.action_scale, nthread=args.batch_threads,
                                        **env_kwargs))
    env.seed(args.seed)
    model = PPO("MlpPolicy", env, seed=args.seed, device="cpu", verbose=0, **IBVS_PPO)
    curve: list[dict[str, float]] = []

    class Periodic(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next = args.eval_every

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next:
                return True
            self.next += args.eval_every
            t = time.perf_counter()
            r = evaluate_ibvs(self.model, args.env_id, args.eval_episodes, args.eval_seed, args.action_scale,
                              env_kwargs, args.batch_threads)
            clock.eval_wall += time.perf_counter() - t
            r.pop("episodes")
            row = {"steps": int(self.num_timesteps), "wall_s": round(clock.wall(), 1), "cpu_s": round(clock.cpu(), 1),
                   **r}
            curve.append(row)
            print(f"  {row['steps']:>8d} steps  wall {row['wall_s']:7.1f} s  cpu {row['cpu_s']:7.1f} s  success "
                  f"{r['success_rate']:.2f}", flush=True)
            return r["success_rate"] < args.goal and clock.wall() < args.budget

    model.learn(total_timesteps=args.max_steps, callback=Periodic())
    wall, cpu = clock.wall(), clock.cpu()
    solved = bool(curve and curve[-1]["success_rate"] >= args.goal)
    confirm = None
    if solved:  # the same 100 episodes one by one through franka_vs_gym.evaluate (outside the clock)
        agent = AgentPolicy(model, args.action_scale, args.env_id)
        r = franka_vs_gym.evaluate(agent, args.env_id, args.eval_episodes, args.eval_seed,
                                   env_kwargs={"observation_type": "features", "action_type": "joint_velocity"})
        confirm = {k: r[k] for k in ("success_rate", "mean_time_to_converge", "failures")}
        if args.save:
            model.save(args.save)
    env.close()
    return {"task": "FrankaIBVS-v0 features agent", "algo": "PPO", "hyperparameters": IBVS_PPO,
            "n_envs": args.n_envs, "action_scale": args.action_scale, "vector_env": "native (mujoco.batch)",
            "solved": solved, "steps": curve[-1]["steps"] if curve else 0, "wall_s": round(wall, 1),
            "cpu_s": round(cpu, 1), "eval_wall_s": round(clock.eval_wall, 1), "curve": curve,
            "confirmation_franka_vs_gym_evaluate": confirm}


def evaluate_panda(model: Any, n: int, seed: int) -> dict[str, float]:
    import gymnasium as gym
    import panda_gym  # noqa: F401  (registers the ids)

    env = gym.make("PandaReach-v3")
    ok = []
    for i in range(n):
        obs, info = env.reset(seed=seed + i)
        while True:
            a, _ = model.predict(obs, deterministic=True)
            obs, _, term, trunc, info = env.step(a)
            if term or trunc:
                break
        ok.append(bool(info.get("is_success", False)))
    env.close()
    return {"success_rate": float(np.mean(ok))}


def run_panda(args: argparse.Namespace) -> dict[str, Any]:
    import torch

    torch.set_num_threads(args.threads)
    try:
        import gymnasium as gym
        import panda_gym  # noqa: F401
    except ImportError:
        raise SystemExit("time_to_solve: --task panda-reach needs panda-gym (pip install panda-gym)") from None
    from stable_baselines3 import DDPG
    from stable_baselines3.common.callbacks import BaseCallback

    clock = Clock()
    env = gym.make("PandaReach-v3")
    model = DDPG(policy="MultiInputPolicy", env=env, seed=args.seed, device="cpu", verbose=0)
    curve: list[dict[str, float]] = []
    every = args.eval_every if args.eval_every_set else 5000

    class Periodic(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.next = every

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next:
                return True
            self.next += every
            t = time.perf_counter()
            r = evaluate_panda(self.model, args.eval_episodes, args.eval_seed)
            clock.eval_wall += time.perf_counter() - t
            row = {"steps": int(self.num_timesteps), "wall_s": round(clock.wall(), 1), "cpu_s": round(clock.cpu(), 1),
                   **r}
            curve.append(row)
            print(f"  {row['steps']:>8d} steps  wall {row['wall_s']:7.1f} s  cpu {row['cpu_s']:7.1f} s  success "
                  f"{r['success_rate']:.2f}", flush=True)
            return r["success_rate"] < args.goal and clock.wall() < args.budget

    model.learn(30_000, callback=Periodic())
    wall, cpu = clock.wall(), clock.cpu()
    env.close()
    return {"task": "PandaReach-v3 (panda-gym)", "algo": "DDPG (SB3 defaults, MultiInputPolicy)",
            "hyperparameters": "SB3 defaults; 30 000 steps budget", "n_envs": 1,
            "solved": bool(curve and curve[-1]["success_rate"] >= args.goal),
            "steps": curve[-1]["steps"] if curve else 0, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
            "eval_wall_s": round(clock.eval_wall, 1), "curve": curve}


def run_ibvs_pixels(args: argparse.Namespace) -> dict[str, Any]:
    """The image agent: ``baselines/train_pixels.py`` (DAgger on the scripted IBVS teacher; its own clock starts
    before anything is made and its held-out evaluations, every ``--eval-every`` DAgger iterations, are inside it),
    stopped at the first evaluation at ``--goal``."""
    import importlib.util
    import tempfile

    spec = importlib.util.spec_from_file_location(
        "train_pixels", Path(__file__).resolve().parents[1] / "baselines" / "train_pixels.py")
    tp = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tp)
    every = max(1, round(args.eval_every / (args.n_envs * 250))) if args.eval_every_set else 3
    with tempfile.TemporaryDirectory() as tmp:
        out = args.save or str(Path(tmp) / "ibvs_pixels")
        targs = tp.build_parser().parse_args([
            "--out", out, "--n-envs", str(args.n_envs), "--seed", str(args.seed), "--eval-seed", str(args.eval_seed),
            "--eval-episodes", str(args.eval_episodes), "--eval-every", str(every), "--stop", str(args.goal),
            "--budget", str(args.budget), "--threads", str(args.threads),
            "--batch-threads", str(args.batch_threads or 1)])
        meta = tp.train(targs)
    curve = meta["curve"]
    first = next((r for r in curve if r["success_rate"] >= args.goal), None)
    row = first or curve[-1]
    return {"task": "FrankaIBVS-v0 image agent (64x48 image, q, dq)", "algo": "DAgger on IBVSPolicy, SB3 PPO policy",
            "hyperparameters": meta["training"]["hyperparameters"] | {"eval_every_iterations": every},
            "n_envs": args.n_envs, "vector_env": "native (mujoco.batch), features+image (features as labels only)",
            "solved": first is not None, "steps": row["samples"], "wall_s": row["wall_s"], "cpu_s": row["cpu_s"],
            "eval_wall_s": meta["training"]["eval_wall_s"], "curve": curve,
            "confirmation_franka_vs_gym_evaluate": {k: meta["evaluation"][k] for k in (
                "success_rate", "mean_time_to_converge", "failures")}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", choices=["ibvs", "panda-reach", "ibvs-pixels"], default="ibvs")
    ap.add_argument("--env-id", default="FrankaIBVS-v0", help=argparse.SUPPRESS)
    ap.add_argument("--goal", type=float, default=0.95, help="success rate to reach (default 0.95)")
    ap.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    ap.add_argument("--eval-seed", type=int, default=10_000, help="first held-out seed (default 10000)")
    ap.add_argument("--eval-episodes", type=int, default=100)
    ap.add_argument("--eval-every", type=int, default=None,
                    help="env steps between evaluations (default 32768 for ibvs, 5000 for panda-reach; "
                    "ibvs-pixels: 3 DAgger iterations of 250 steps of each robot)")
    ap.add_argument("--n-envs", type=int, default=16, help="robots in the native vector env (ibvs, ibvs-pixels; "
                    "default 16)")
    ap.add_argument("--action-scale", type=float, default=0.5, help="rad/s of an action of 1 (ibvs; default 0.5)")
    ap.add_argument("--max-steps", type=int, default=2_000_000, help="training steps at most (ibvs)")
    ap.add_argument("--budget", type=float, default=3600.0, help="give up after this wall time, s (default 3600)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--batch-threads", type=int, default=None, help="mujoco.batch threads (default min(N, CPUs))")
    ap.add_argument("--save", default=None, help="save the solving agent here (ibvs; ibvs-pixels: "
                    "<save>.zip, .json and _curve.png)")
    ap.add_argument("--json", default=None, help="write the result to this JSON file (must not exist)")
    args = ap.parse_args(argv)
    args.eval_every_set = args.eval_every is not None
    if args.eval_every is None:
        args.eval_every = 32_768
    for name in ("eval_every", "eval_episodes", "n_envs", "max_steps", "threads"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    if not 0 < args.goal <= 1:
        ap.error("--goal must be in (0, 1]")
    if args.json and Path(args.json).exists():
        ap.error(f"{args.json} exists; choose another --json path")
    machine = {"cpus": os.cpu_count(), "load_at_start": _load()}
    print(f"time to solve: {args.task}, goal {args.goal:.0%} on {args.eval_episodes} held-out episodes; "
          f"{machine['cpus']} CPUs, load {machine['load_at_start']}", flush=True)
    result = {"ibvs": run_ibvs, "panda-reach": run_panda, "ibvs-pixels": run_ibvs_pixels}[args.task](args)
    machine["load_at_end"] = _load()
    cmd = " ".join(argv if argv is not None else sys.argv[1:])
    result.update({"goal": args.goal, "seed": args.seed, "eval_seed": args.eval_seed,
                   "eval_episodes": args.eval_episodes, "machine": machine,
                   "command": f"python scripts/time_to_solve.py {cmd}".strip()})
    status = "solved" if result["solved"] else "NOT solved"
    print(f"{result['task']}: {status} after {result['steps']} steps: wall {result['wall_s']:.1f} s (evaluations "
          f"{result['eval_wall_s']:.1f} s), process CPU {result['cpu_s']:.1f} s; load {machine['load_at_start']} -> "
          f"{machine['load_at_end']}", flush=True)
    if result.get("confirmation_franka_vs_gym_evaluate"):
        print(f"  franka_vs_gym.evaluate on the same episodes: {result['confirmation_franka_vs_gym_evaluate']}")
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0 if result["solved"] else 1


if __name__ == "__main__":
    sys.exit(main())
