#!/usr/bin/env python
"""Time to solve: wall-clock time from nothing to an agent with >= 95 % success on 100 held-out episodes.

    python scripts/time_to_solve.py                        # FrankaIBVS-v0, features agent (PPO, native vector env)
    python scripts/time_to_solve.py --task FrankaPBVS-v0 --robot fr3   # any registered env id, on either robot
    python scripts/time_to_solve.py --task FrankaPBVS-v0 --save franka_vs_gym/policies/agents/pbvs_ppo  # + ship it
    python scripts/time_to_solve.py --task panda-reach     # panda-gym's PandaReach-v3, its documented SB3 recipe
    python scripts/time_to_solve.py --task ibvs-pixels     # FrankaIBVS-v0 from the camera image (DAgger student)
    python scripts/time_to_solve.py --json result.json     # also write the result (the file must not exist)

"From nothing" starts the clock before the environments and the untrained model are made; it stops when a periodic
evaluation on the held-out episodes (seeds ``--eval-seed`` ... ``--eval-seed + 99``; training draws its episodes
from seeds 0 ... n_envs - 1) first reaches ``--goal``. The evaluations are inside the clock (their share is
reported). Also reported: the process CPU time (all threads), which is what the wall time would be on a quiet
machine with as many cores as threads used, and the machine's load (``os.getloadavg``) at start and end: on a
shared machine the wall time says more about the neighbours than about the method.

The joint-velocity envs (``--task FrankaIBVS-v0`` (alias ``ibvs``), ``FrankaPBVS-v0``, ``FrankaIBVSEyeToHand-v0``,
``FrankaPBVSEyeToHand-v0``; ``--robot fer`` or ``fr3``): PPO with the env's recipe (:data:`RECIPES`) on
``franka_vs_gym.envs.sb3.make_agent_vec_env`` (``n_envs`` robots on one ``mujoco.batch``, the flat servo vector
observation and [-1, 1] actions of ``baselines/train_sb3.py``), evaluated with all 100 held-out episodes stepped
together on the same native vector env (the same episodes, bit for bit, as ``franka_vs_gym.evaluate`` with that
seed, which confirms the final agent). With ``--save PATH`` the final agent is written as ``PATH.zip`` and a sidecar
``PATH.json`` (the schema of the shipped ``ibvs_ppo.json`` plus ``robot``, the hyper-parameters, wall and CPU
training time, the training curve, and ``franka_vs_gym.evaluate`` on 100 test episodes (seeds ``--test-seed`` ...:
neither the training nor the stopping rule saw them) on its robot and on the other robot); it loads with
``franka_vs_gym.policies.load_agent`` and ``franka-vs evaluate PATH.zip``. The torque envs
(``FrankaTorqueTracking-v0``, ``FrankaVisualTorque-v0``) run the torque recipe, ``baselines/train_torque.py``'s
``train(env_id, robot, seed, out, ...)``, and report its curve and evaluation in the same format. PandaReach-v3
(``--task panda-reach``, needs ``pip install panda-gym``): panda-gym's documented recipe,
``DDPG(policy="MultiInputPolicy", env)`` with SB3's defaults and a 30 000-step budget (panda-gym's "Train with
stable-baselines3" page), evaluated on 100 episodes the same way (deterministic actions, success =
``info["is_success"]`` at the episode's end).
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
                  nthread: int | None, observation_layout: str | None = None) -> dict[str, float]:
    """The first episode of each of n robots (robot i reset with seed + i, as franka_vs_gym.evaluate's episode i),
    deterministic actions, all stepped together: (success rate, mean time to converge of the successes)."""
    from franka_vs_gym.envs.sb3 import make_agent_vec_env

    key = (env_id, n, action_scale, nthread, observation_layout, json.dumps(env_kwargs, sort_keys=True))
    if key not in _EVAL_ENVS:  # made once (its robots' models), reset with the held-out seeds at each evaluation
        _EVAL_ENVS[key] = make_agent_vec_env(env_id, n, action_scale, nthread=nthread,
                                             observation_layout=observation_layout, **env_kwargs)
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


#: the torque envs' recipe: a script with ``train(env_id, robot, seed, out, ...)`` returning the agent's sidecar dict
TORQUE_RECIPE = Path(__file__).resolve().parents[1] / "baselines" / "train_torque.py"
VELOCITY_ENVS = ("FrankaIBVS-v0", "FrankaPBVS-v0", "FrankaIBVSEyeToHand-v0", "FrankaPBVSEyeToHand-v0")
TORQUE_ENVS = ("FrankaTorqueTracking-v0", "FrankaVisualTorque-v0")
ROBOTS = ("fer", "fr3")
LAYOUTS = ("servo-vector/2", "servo-pose-vector/1")  # franka_vs_gym.envs.wrappers.OBS_LAYOUT, POSE_LAYOUT
#: per joint-velocity env: the PPO hyper-parameters, the robots of the native vector env, the action scale (rad/s
#: of an action of 1) and the observation (``--observation``: the servo vector, or with the tag's pose error); the
#: IBVS features agent's recipe for every env
RECIPES: dict[str, dict[str, Any]] = {
    env_id: {"hyperparameters": IBVS_PPO, "n_envs": 16, "action_scale": 0.5, "observation_layout": LAYOUTS[0]}
    for env_id in VELOCITY_ENVS}


def _other(robot: str) -> str:
    return "fr3" if robot == "fer" else "fer"


def _summary(r: dict[str, Any], seed: int, robot: str) -> dict[str, Any]:
    """franka_vs_gym.evaluate's summary in strict JSON (no NaN), with its seed and robot."""
    out = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items() if k != "episodes"}
    return out | {"seed": seed, "robot": robot}


def run_velocity(args: argparse.Namespace) -> dict[str, Any]:
    """PPO on a joint-velocity env (the env's :data:`RECIPES` row), stopped at the first held-out check at
    ``--goal`` or at the budget; with ``--save``, the agent and its sidecar."""
    import torch

    torch.set_num_threads(args.threads)
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import VecMonitor

    import franka_vs_gym
    from franka_vs_gym.envs.sb3 import make_agent_vec_env
    from franka_vs_gym.envs.wrappers import AgentPolicy

    recipe = RECIPES[args.task]
    hp = recipe["hyperparameters"]
    n_envs = args.n_envs or recipe["n_envs"]
    scale = args.action_scale or recipe["action_scale"]
    layout = args.observation or recipe["observation_layout"]
    env_kwargs: dict[str, Any] = {} if args.robot == "fer" else {"robot": args.robot}
    load0 = _load()
    clock = Clock()
    env = VecMonitor(make_agent_vec_env(args.task, n_envs, scale, nthread=args.batch_threads,
                                        observation_layout=layout, **env_kwargs))
    env.seed(args.seed)
    model = PPO("MlpPolicy", env, seed=args.seed, device="cpu", verbose=0, **hp)
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
            r = evaluate_ibvs(self.model, args.task, args.eval_episodes, args.eval_seed, scale, env_kwargs,
                              args.batch_threads, layout)
            clock.eval_wall += time.perf_counter() - t
            r.pop("episodes")
            r = {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in r.items()}
            row = {"steps": int(self.num_timesteps), "wall_s": round(clock.wall(), 1), "cpu_s": round(clock.cpu(), 1),
                   **r}
            curve.append(row)
            print(f"  {row['steps']:>8d} steps  wall {row['wall_s']:7.1f} s  cpu {row['cpu_s']:7.1f} s  success "
                  f"{r['success_rate']:.2f}", flush=True)
            return r["success_rate"] < args.goal and clock.wall() < args.budget and clock.cpu() < args.cpu_budget

    model.learn(total_timesteps=args.max_steps, callback=Periodic())
    wall, cpu = clock.wall(), clock.cpu()
    solved = bool(curve and curve[-1]["success_rate"] >= args.goal)
    eval_kw = {"observation_type": "features", "action_type": "joint_velocity"}
    agent = AgentPolicy(model, scale, args.task, env_kwargs, layout)
    confirm = None
    if solved:  # the same 100 episodes one by one through franka_vs_gym.evaluate (outside the clock)
        r = franka_vs_gym.evaluate(agent, args.task, args.eval_episodes, args.eval_seed,
                                   env_kwargs=eval_kw | env_kwargs)
        confirm = {k: r[k] for k in ("success_rate", "mean_time_to_converge", "failures")}
    env.close()
    steps = curve[-1]["steps"] if curve else 0
    result = {"task": f"{args.task} features agent on the {args.robot.upper()}", "algo": "PPO",
              "hyperparameters": hp, "n_envs": n_envs, "action_scale": scale, "observation_layout": layout,
              "vector_env": "native (mujoco.batch)",
              "solved": solved, "steps": steps, "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
              "eval_wall_s": round(clock.eval_wall, 1), "curve": curve, "confirmation_franka_vs_gym_evaluate": confirm}
    if args.save:
        out = Path(args.save)
        out = out.with_suffix("") if out.suffix == ".zip" else out
        zip_path = out.with_name(out.name + ".zip")
        meta_path = out.with_name(out.name + ".json")
        out.parent.mkdir(parents=True, exist_ok=True)
        model.save(str(zip_path))
        cmd = " ".join(args.argv if args.argv is not None else sys.argv[1:])
        meta: dict[str, Any] = {
            "algo": "ppo", "env_id": args.task, "robot": args.robot, "env_kwargs": env_kwargs, "action_scale": scale,
            "action_type": "joint_velocity", "observation_layout": layout, "timesteps": steps,
            "seed": args.seed, "n_envs": n_envs, "batched": True, "hyper_parameters": hp, "torch_threads": args.threads,
            "goal": args.goal, "solved": solved, "train_time_s": round(wall, 1), "train_cpu_s": round(cpu, 1),
            "eval_wall_s": round(clock.eval_wall, 1), "load_at_start": load0, "load_at_end": _load(),
            "command": f"python scripts/time_to_solve.py {cmd}".strip(),
            "training_curve": [{"steps": r["steps"], "wall_s": r["wall_s"], "cpu_s": r["cpu_s"],
                                "success_rate": r["success_rate"]} for r in curve],
            "training_curve_seed": args.eval_seed}
        meta_path.write_text(json.dumps(meta, indent=2))
        shipped = AgentPolicy.load(zip_path)  # the saved files, through the loading path users take
        for key, robot in (("evaluation", args.robot), ("evaluation_other_robot", _other(args.robot))):
            kw = eval_kw | {"robot": robot}
            r = franka_vs_gym.evaluate(shipped, args.task, args.test_episodes, args.test_seed, env_kwargs=kw)
            meta[key] = _summary(r, args.test_seed, robot)
            print(f"  {key}: {robot.upper()}, {args.test_episodes} test episodes (seeds {args.test_seed}...): success "
                  f"{r['success_rate']:.2f}, failures {r['failures']}", flush=True)
        meta_path.write_text(json.dumps(meta, indent=2))
        print(f"saved {zip_path} ({zip_path.stat().st_size / 1e3:.0f} kB) and {meta_path}", flush=True)
        result["evaluation"] = meta["evaluation"]
        result["evaluation_other_robot"] = meta["evaluation_other_robot"]
    return result


def run_torque(args: argparse.Namespace) -> dict[str, Any]:
    """The torque envs: the torque recipe's ``baselines.train_torque:train(env_id, robot, seed, out, ...)`` (its
    own clock, curve and evaluations), reported in this script's format."""
    import importlib.util
    import tempfile

    path = TORQUE_RECIPE
    if not path.is_file():
        raise SystemExit(f"time_to_solve: --task {args.task} needs the torque recipe baselines/train_torque.py "
                         "(train(env_id, robot, seed, out, ...)), which this checkout does not have")
    spec = importlib.util.spec_from_file_location("train_torque", path)
    tt = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tt)
    if not callable(getattr(tt, "train", None)):
        raise SystemExit("time_to_solve: baselines/train_torque.py has no train(env_id, robot, seed, out, ...)")
    cmd = " ".join(args.argv if args.argv is not None else sys.argv[1:])
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.save) if args.save else Path(tmp) / "torque_agent"
        kw: dict[str, Any] = {"eval_episodes": args.test_episodes, "eval_seed": args.test_seed,
                              "threads": args.threads, "command": f"python scripts/time_to_solve.py {cmd}".strip()}
        if args.max_steps_set:
            kw["timesteps"] = args.max_steps
        meta = tt.train(args.task, args.robot, args.seed, out, **kw)
    ev = meta.get("evaluation") or {}
    curve = meta.get("training_curve", [])
    return {"task": f"{args.task} torque agent on the {args.robot.upper()}", "algo": meta.get("algo", "?").upper(),
            "hyperparameters": meta.get("hyper_parameters"), "n_envs": meta.get("n_envs"),
            "solved": bool(ev.get("success_rate", 0.0) >= args.goal), "steps": meta.get("timesteps", 0),
            "wall_s": meta.get("train_time_s", float("nan")), "cpu_s": meta.get("train_cpu_s", float("nan")),
            "eval_wall_s": 0.0, "curve": curve, "evaluation": ev,
            "evaluation_other_robot": meta.get("evaluation_other_robot")}


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


TASKS = {"ibvs": "FrankaIBVS-v0"}  # the historical name of the IBVS features task


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--task", default="FrankaIBVS-v0", metavar="TASK",
                    help=f"a registered env id ({', '.join(VELOCITY_ENVS + TORQUE_ENVS)}; 'ibvs' is FrankaIBVS-v0), "
                    "panda-reach or ibvs-pixels (default FrankaIBVS-v0)")
    ap.add_argument("--robot", choices=ROBOTS, default="fer", help="the simulated arm of the env tasks (default fer)")
    ap.add_argument("--goal", type=float, default=0.95, help="success rate to reach (default 0.95)")
    ap.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    ap.add_argument("--eval-seed", type=int, default=10_000, help="first held-out seed (default 10000)")
    ap.add_argument("--eval-episodes", type=int, default=100)
    ap.add_argument("--test-seed", type=int, default=20_000, help="first seed of the saved agent's test episodes "
                    "(--save; default 20000)")
    ap.add_argument("--test-episodes", type=int, default=100, help="test episodes of the saved agent (default 100)")
    ap.add_argument("--eval-every", type=int, default=None,
                    help="env steps between evaluations (default 32768 for the env tasks, 5000 for panda-reach; "
                    "ibvs-pixels: 3 DAgger iterations of 250 steps of each robot)")
    ap.add_argument("--n-envs", type=int, default=None, help="robots in the native vector env (default: the env's "
                    "recipe, 16; ibvs-pixels 16)")
    ap.add_argument("--action-scale", type=float, default=None, help="rad/s of an action of 1 (joint-velocity envs; "
                    "default: the env's recipe, 0.5)")
    ap.add_argument("--observation", choices=LAYOUTS, default=None, help="the agent's observation (joint-velocity "
                    "envs; default: the env's recipe)")
    ap.add_argument("--max-steps", type=int, default=None, help="training steps at most (default 2000000; the "
                    "torque envs: the torque recipe's default)")
    ap.add_argument("--budget", type=float, default=3600.0, help="give up after this wall time, s (default 3600)")
    ap.add_argument("--cpu-budget", type=float, default=1800.0, help="give up after this process CPU time, s "
                    "(joint-velocity envs; default 1800: the 30 minutes of a training)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    ap.add_argument("--batch-threads", type=int, default=None, help="mujoco.batch threads (default min(N, CPUs))")
    ap.add_argument("--save", default=None, help="save the final agent as <save>.zip + <save>.json (env tasks; "
                    "ibvs-pixels: <save>.zip, .json and _curve.png)")
    ap.add_argument("--json", default=None, help="write the result to this JSON file (must not exist)")
    args = ap.parse_args(argv)
    args.argv = argv
    args.task = TASKS.get(args.task, args.task)
    if args.task not in VELOCITY_ENVS + TORQUE_ENVS + ("panda-reach", "ibvs-pixels"):
        known = ", ".join(VELOCITY_ENVS + TORQUE_ENVS)
        ap.error(f"--task: unknown task {args.task!r}; use a registered env id ({known}), ibvs, panda-reach or "
                 "ibvs-pixels")
    args.eval_every_set = args.eval_every is not None
    if args.eval_every is None:
        args.eval_every = 32_768
    args.max_steps_set = args.max_steps is not None
    if args.max_steps is None:
        args.max_steps = 2_000_000
    if args.n_envs is None and args.task == "ibvs-pixels":
        args.n_envs = 16
    for name in ("eval_every", "eval_episodes", "test_episodes", "n_envs", "max_steps", "threads"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    if args.action_scale is not None and not args.action_scale > 0:
        ap.error("--action-scale must be > 0")
    if not 0 < args.goal <= 1:
        ap.error("--goal must be in (0, 1]")
    if args.json and Path(args.json).exists():
        ap.error(f"{args.json} exists; choose another --json path")
    if args.save and args.task in VELOCITY_ENVS + TORQUE_ENVS:
        out = Path(args.save)
        out = out.with_suffix("") if out.suffix == ".zip" else out
        for p in (out.with_name(out.name + ".zip"), out.with_name(out.name + ".json")):
            if p.exists():
                ap.error(f"--save: {p} exists; choose another path (nothing is overwritten)")
    machine = {"cpus": os.cpu_count(), "load_at_start": _load()}
    print(f"time to solve: {args.task}, goal {args.goal:.0%} on {args.eval_episodes} held-out episodes; "
          f"{machine['cpus']} CPUs, load {machine['load_at_start']}", flush=True)
    if args.task in VELOCITY_ENVS:
        result = run_velocity(args)
    elif args.task in TORQUE_ENVS:
        result = run_torque(args)
    else:
        result = {"panda-reach": run_panda, "ibvs-pixels": run_ibvs_pixels}[args.task](args)
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
