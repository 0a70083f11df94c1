#!/usr/bin/env python
"""Train PPO with RLlib on a franka_vs_gym environment: env runners on a Ray cluster, each stepping its robots on
the batched vector env (gymnasium.make_vec's native vector env on mujoco.batch).

    python baselines/train_rllib.py --env-id FrankaIBVS-v0 --iterations 50 [--address auto] \
        [--env-runners 2 --envs-per-runner 16] [--out runs/rllib/ibvs]

Needs the ``[scale]`` extra (Ray with RLlib). Without ``--address`` a local Ray instance is started. Each env
runner makes ``gymnasium.make_vec(env_id, num_envs=envs_per_runner, vectorization_mode="vector_entry_point")``
(RLlib's ``gym_env_vectorize_mode``), so one runner process steps all its robots in one batched call; the Dict
observation is flattened by RLlib's ``FlattenObservations`` connector, actions are clipped to the action space.
Progress (mean episode return, env steps sampled, steps/s) is printed after each iteration; the final checkpoint
and a JSON summary are written to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env-id", default="FrankaIBVS-v0")
    p.add_argument("--env-kwargs", default="{}", help="JSON object of gymnasium.make keyword arguments")
    p.add_argument("--iterations", type=int, default=50, help="RLlib training iterations")
    p.add_argument("--address", default=None, help="Ray cluster address ('auto', 'ray://host:10001'); default: a "
                   "local Ray instance")
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local Ray instance (default: all)")
    p.add_argument("--env-runners", type=int, default=1, help="RLlib env runner processes")
    p.add_argument("--envs-per-runner", type=int, default=8, help="robots per env runner (one batch each)")
    p.add_argument("--batch-threads", type=int, default=1, help="mujoco.batch threads in each env runner")
    p.add_argument("--train-batch", type=int, default=4000, help="env steps per training iteration")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="runs/rllib/agent", help="output folder (checkpoint and summary.json)")
    p.add_argument("--force", action="store_true", help="write into an existing output folder")
    p.add_argument("--smoke", action="store_true", help="one tiny iteration (CI)")
    return p


def make_batched_env(ctx: Any):
    """RLlib env creator: ``ctx`` is RLlib's EnvContext (the env_config plus ``num_envs`` when RLlib asks for a
    vector env); returns the batched vector env."""
    import franka_vs_gym  # noqa: F401  (registers the ids in the env runner process)
    from franka_vs_gym.envs.vector import FrankaVectorEnv

    cfg = dict(ctx)
    env_id = cfg.pop("env_id")
    num_envs = int(cfg.pop("num_envs", 1))
    return FrankaVectorEnv(env_id, num_envs, **cfg)


def build_config(args: argparse.Namespace, env_kwargs: dict[str, Any]):
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.connectors.env_to_module import FlattenObservations
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig
    from ray.tune.registry import register_env

    register_env("franka_batched", make_batched_env)
    train_batch = 64 if args.smoke else args.train_batch
    env_config = {"env_id": args.env_id, "nthread": args.batch_threads, "clip_actions": True, **env_kwargs}
    return (
        PPOConfig()
        .environment(env="franka_batched", env_config=env_config)
        .env_runners(num_env_runners=args.env_runners, num_envs_per_env_runner=args.envs_per_runner,
                     gym_env_vectorize_mode="vector_entry_point",
                     env_to_module_connector=lambda env, spaces=None, device=None: FlattenObservations(),
                     rollout_fragment_length="auto")
        .training(train_batch_size_per_learner=train_batch, minibatch_size=min(256, train_batch),
                  num_epochs=1 if args.smoke else 10, lr=3e-4, gamma=0.98)
        .rl_module(model_config=DefaultModelConfig(fcnet_hiddens=[128, 128]))
        .debugging(seed=args.seed)
    )


def train(args: argparse.Namespace) -> dict[str, Any]:
    env_kwargs = json.loads(args.env_kwargs)
    if not isinstance(env_kwargs, dict):
        raise ValueError("--env-kwargs must be a JSON object")
    if args.iterations < 1 or args.env_runners < 0 or args.envs_per_runner < 1:
        raise ValueError("--iterations and --envs-per-runner must be >= 1, --env-runners >= 0")
    out = Path(args.out)
    if out.exists() and any(out.iterdir()) and not args.force:
        raise FileExistsError(f"{out} exists and is not empty; pass --force to write into it")
    from franka_vs_gym.scale import ray_session

    iterations = 1 if args.smoke else args.iterations
    history = []
    with ray_session(args.address, args.num_cpus):
        algo = build_config(args, env_kwargs).build_algo()
        try:
            t0 = time.perf_counter()
            for it in range(iterations):
                r = algo.train()
                runners = r.get("env_runners", {})
                row = {"iteration": it + 1,
                       "episode_return_mean": runners.get("episode_return_mean"),
                       "env_steps_sampled": runners.get("num_env_steps_sampled_lifetime"),
                       "time_s": time.perf_counter() - t0}
                history.append(row)
                print(f"iteration {it + 1}/{iterations}: mean episode return {row['episode_return_mean']}, "
                      f"env steps {row['env_steps_sampled']}, {row['time_s']:.0f} s", flush=True)
            vector_envs = sorted(set(algo.env_runner_group.foreach_env_runner(
                lambda runner: type(runner.env.unwrapped).__name__ if runner.env is not None else "none")) - {"none"})
            out.mkdir(parents=True, exist_ok=True)
            checkpoint = algo.save_to_path(str((out / "checkpoint").resolve()))
        finally:
            algo.stop()
    summary = {"env_id": args.env_id, "env_kwargs": env_kwargs, "iterations": iterations,
               "env_runners": args.env_runners, "envs_per_runner": args.envs_per_runner,
               "vector_env": vector_envs, "checkpoint": str(checkpoint), "history": history,
               "command": "python " + " ".join(sys.argv)}
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=str))
    print(f"saved {checkpoint} and {out / 'summary.json'}", flush=True)
    return summary


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        train(args)
    except (ValueError, FileExistsError, RuntimeError) as e:
        print(f"train_rllib: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
