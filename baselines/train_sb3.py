"""Train a stable-baselines3 agent (SAC or PPO) on a visual-servoing env: features observations, joint velocities.

``--env`` picks the env (FrankaIBVS-v0 by default; FrankaPBVS-v0, FrankaIBVSEyeToHand-v0, FrankaPBVSEyeToHand-v0:
the same observation keys) and ``--robot`` the arm (fer or fr3; stored in the sidecar and its env kwargs).

The agent acts in [-1, 1]^7, scaled to +-``--action-scale`` rad/s, and observes the flat vector of
``franka_vs_gym.envs.wrappers.servo_vector`` (feature error, features, depth error, q, dq, visibility). Progress
is printed every ``--log-every`` steps and written to TensorBoard (``--tensorboard``, default ``runs/sb3``). At the
end the model is saved as ``<out>.zip`` with a JSON sidecar ``<out>.json`` (env id, env kwargs, action scale), and
evaluated with ``franka_vs_gym.evaluate`` on the unwrapped environment (the same interface as the classical IBVS
baseline).

Examples::

    python baselines/train_sb3.py --algo sac --timesteps 60000 --out runs/sb3/ibvs_sac
    python baselines/train_sb3.py --smoke            # a few hundred steps (CI)
    tensorboard --logdir runs/sb3
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--algo", choices=["sac", "ppo"], default="sac")
    p.add_argument("--env", "--env-id", dest="env_id", default="FrankaIBVS-v0",
                   choices=["FrankaIBVS-v0", "FrankaPBVS-v0", "FrankaIBVSEyeToHand-v0", "FrankaPBVSEyeToHand-v0"],
                   help="the joint-velocity env to train on (default FrankaIBVS-v0)")
    p.add_argument("--robot", choices=["fer", "fr3"], default=None, help="the simulated arm (default: the env's, "
                   "the FER)")
    p.add_argument("--timesteps", type=int, default=60_000, help="environment steps to train for")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--n-envs", type=int, default=0, help="environments stepped together (default: 1 for SAC, 8 for "
                   "PPO; one process)")
    p.add_argument("--action-scale", type=float, default=0.5, help="joint speed (rad/s) of an action of 1")
    p.add_argument("--out", default="runs/sb3/ibvs_agent", help="output path without .zip")
    p.add_argument("--tensorboard", default="runs/sb3", help="TensorBoard log folder ('' to disable)")
    p.add_argument("--log-every", type=int, default=2000, help="print progress every N steps")
    p.add_argument("--eval-episodes", type=int, default=50, help="episodes of the final evaluation (0: none)")
    p.add_argument("--eval-seed", type=int, default=10_000)
    p.add_argument("--threads", type=int, default=1, help="torch threads (keep 1 on a shared machine)")
    p.add_argument("--force", action="store_true", help="overwrite an existing output")
    p.add_argument("--batched", action="store_true", help="step the environments' physics together on mujoco.batch "
                   "(gymnasium.make_vec's native vector env) instead of one Python env each")
    p.add_argument("--batch-threads", type=int, default=None, help="threads of the batch (default min(n-envs, CPUs))")
    p.add_argument("--smoke", action="store_true", help="a few hundred steps, tiny evaluation (CI smoke test)")
    p.add_argument("--env-kwargs", default="{}", help="JSON dict of extra gymnasium.make keyword arguments")
    return p


def _progress_callback(log_every: int, total: int):
    from stable_baselines3.common.callbacks import BaseCallback

    class Progress(BaseCallback):
        """Prints steps, fps, episodes, recent success rate and return; logs success rate to TensorBoard."""

        def __init__(self) -> None:
            super().__init__()
            self.successes: deque[float] = deque(maxlen=100)
            self.returns: deque[float] = deque(maxlen=100)
            self.episodes = 0
            self.t0 = time.perf_counter()
            self._ret = None
            self.next_log = log_every

        def _on_step(self) -> bool:
            rewards = self.locals["rewards"]
            if self._ret is None:
                self._ret = np.zeros(len(rewards))
            self._ret += rewards
            for i, (done, info) in enumerate(zip(self.locals["dones"], self.locals["infos"], strict=True)):
                if done:
                    self.episodes += 1
                    self.successes.append(float(info.get("is_success", False)))
                    self.returns.append(float(self._ret[i]))
                    self._ret[i] = 0.0
            if self.successes:
                self.logger.record("rollout/success_rate", float(np.mean(self.successes)))
            n = self.num_timesteps
            if n >= self.next_log or n >= total:
                self.next_log += log_every
                dt = time.perf_counter() - self.t0
                sr = np.mean(self.successes) if self.successes else float("nan")
                ret = np.mean(self.returns) if self.returns else float("nan")
                print(f"[{n:>8d}/{total}] {n / dt:6.0f} steps/s  episodes {self.episodes:5d}  "
                      f"success (last 100) {sr:5.2f}  return {ret:8.3f}  elapsed {dt / 60:5.1f} min", flush=True)
            return True

    return Progress()


def train(args: argparse.Namespace) -> dict[str, Any]:
    import torch

    torch.set_num_threads(max(1, args.threads))
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.monitor import Monitor

    import franka_vs_gym
    from franka_vs_gym.envs.wrappers import OBS_LAYOUT, AgentPolicy, make_agent_env

    env_kwargs = json.loads(args.env_kwargs)
    if not isinstance(env_kwargs, dict):
        raise ValueError("--env-kwargs must be a JSON object")
    if args.robot is not None:
        if env_kwargs.get("robot", args.robot) != args.robot:
            raise ValueError(f"--robot {args.robot} and --env-kwargs robot {env_kwargs['robot']!r} differ")
        env_kwargs["robot"] = args.robot
    out = Path(args.out)
    if out.suffix == ".zip":
        out = out.with_suffix("")
    zip_path, meta_path = out.with_suffix(".zip"), out.with_suffix(".json")
    if zip_path.exists() and not args.force:
        raise FileExistsError(f"{zip_path} exists; pass --force to overwrite it")
    timesteps = 400 if args.smoke else int(args.timesteps)
    if timesteps < 1:
        raise ValueError(f"--timesteps must be >= 1, got {timesteps}")
    from stable_baselines3.common.vec_env import DummyVecEnv

    n_envs = args.n_envs if args.n_envs else (1 if args.algo == "sac" else 8)
    if n_envs < 1:
        raise ValueError(f"--n-envs must be >= 1, got {n_envs}")
    if args.batched:  # the robots' physics on one mujoco.batch (franka_vs_gym.envs.vector)
        from stable_baselines3.common.vec_env import VecMonitor

        from franka_vs_gym.envs.sb3 import make_agent_vec_env

        env = VecMonitor(make_agent_vec_env(args.env_id, n_envs, args.action_scale, nthread=args.batch_threads,
                                            **env_kwargs))
    else:
        env = DummyVecEnv([lambda: Monitor(make_agent_env(args.env_id, args.action_scale, **env_kwargs))
                           for _ in range(n_envs)])
    env.seed(args.seed)
    tb = args.tensorboard or None
    if args.algo == "sac":
        model = SAC("MlpPolicy", env, learning_rate=3e-4, buffer_size=200_000,
                    learning_starts=100 if args.smoke else 2000, batch_size=256, gamma=0.98, tau=0.01,
                    train_freq=1, gradient_steps=1, policy_kwargs={"net_arch": [128, 128]}, seed=args.seed,
                    tensorboard_log=tb, device="cpu", verbose=0)
    else:
        model = PPO("MlpPolicy", env, learning_rate=3e-4, n_steps=32 if args.smoke else 256, batch_size=256,
                    n_epochs=10, gamma=0.98, gae_lambda=0.95, clip_range=0.2, ent_coef=0.0,
                    policy_kwargs={"net_arch": [128, 128], "log_std_init": -1.0}, seed=args.seed,
                    tensorboard_log=tb, device="cpu", verbose=0)
    print(f"training {args.algo.upper()} on {args.env_id} for {timesteps} steps with {n_envs} env(s) (action scale "
          f"{args.action_scale} rad/s, TensorBoard: {tb or 'off'})", flush=True)
    t0 = time.perf_counter()
    model.learn(total_timesteps=timesteps, callback=_progress_callback(100 if args.smoke else args.log_every,
                                                                       timesteps),
                tb_log_name=f"{args.algo}_{args.env_id}")
    train_time = time.perf_counter() - t0
    out.parent.mkdir(parents=True, exist_ok=True)
    model.save(str(zip_path), exclude=["replay_buffer"])
    meta = {"algo": args.algo, "env_id": args.env_id, "robot": str(env_kwargs.get("robot", "fer")),
            "env_kwargs": env_kwargs, "action_scale": args.action_scale,
            "action_type": "joint_velocity", "observation_layout": OBS_LAYOUT, "timesteps": timesteps,
            "seed": args.seed, "n_envs": n_envs, "batched": bool(args.batched), "train_time_s": round(train_time, 1),
            "command": "python " + " ".join(sys.argv)}
    meta_path.write_text(json.dumps(meta, indent=2))
    print(f"saved {zip_path} ({zip_path.stat().st_size / 1e6:.2f} MB) and {meta_path}; "
          f"trained in {train_time / 60:.1f} min", flush=True)
    result: dict[str, Any] = {"model": str(zip_path), "train_time_s": train_time}
    n_eval = 2 if args.smoke else args.eval_episodes
    if n_eval > 0:
        agent = AgentPolicy.load(zip_path)
        kw = {"observation_type": "features", "action_type": "joint_velocity", **env_kwargs}
        r = franka_vs_gym.evaluate(agent, args.env_id, n_eval, args.eval_seed, env_kwargs=kw)
        print(f"evaluation over {n_eval} episodes (seeds {args.eval_seed}...): success rate "
              f"{r['success_rate']:.2f}, mean time to converge {r['mean_time_to_converge']:.2f} s, median final "
              f"error {r['median_final_error']:.4f}, failures {r['failures']}", flush=True)
        summary = {k: (None if isinstance(v, float) and not np.isfinite(v) else v)  # strict JSON: no NaN
                   for k, v in r.items() if k != "episodes"}
        meta["evaluation"] = summary | {"seed": args.eval_seed}
        meta_path.write_text(json.dumps(meta, indent=2))
        result["evaluation"] = r
    return result


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        train(args)
    except (ValueError, FileExistsError) as e:
        print(f"train_sb3: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
