"""Train a residual torque agent (PPO) on FrankaTorqueTracking-v0 or FrankaVisualTorque-v0, FER or FR3.

The structure (franka_vs_gym.envs.torque_agent): the env's torque action = a fixed, model-based base torque
computed from the env's own observation with the agent's plant model (computed torque for tracking; the scripted
IBVS law's joint velocities through a joint velocity loop for visual torque) + the network's residual in
[-1, 1]^7 times half the env's torque action scale, clipped to the torque limits. The network (MLP 64x64) sees a
normalised flat observation and learns the residual with PPO. ``--randomize`` trains on the env's own dynamics
randomisation (:data:`RANDOMIZATION`: link masses, friction, an undeclared payload), where the base's model is
wrong and the residual has work to do.

At the end the agent is saved as ``<out>.zip`` with its JSON sidecar ``<out>.json`` (env, robot, kwargs,
structure, hyper-parameters, command, training curve, wall and CPU time, and the final evaluation on 100 held-out
episodes, seeds 10000..., on its robot and on the other robot, beside the base alone on the same episodes).

    python baselines/train_torque.py --env-id FrankaTorqueTracking-v0 --robot fer --timesteps 300000 \
        --randomize --out runs/torque/tracking_fer
    python baselines/train_torque.py --smoke --out /tmp/smoke      # a few hundred steps

``train(...)`` is the same from Python (``scripts/time_to_solve.py``, ``scripts/sim_to_real.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

#: the dynamics randomisation of ``--randomize`` (FrankaEnv options): link masses and inertias +-30 %, the joint
#: friction law x0.5-2, an undeclared payload of 0-1.5 kg held 5 cm in front of the flange
RANDOMIZATION = {"link_mass_range": [0.7, 1.3], "friction_scale_range": [0.5, 2.0], "payload_mass_range": [0.0, 1.5],
                 "payload_declared": False}
PPO_KWARGS = {"learning_rate": 3e-4, "n_steps": 256, "batch_size": 256, "n_epochs": 10, "gamma": 0.99,
              "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0,
              "policy_kwargs": {"net_arch": [64, 64], "log_std_init": -2.0}}
ENV_IDS = ("FrankaTorqueTracking-v0", "FrankaVisualTorque-v0")
ROBOTS = ("fer", "fr3")


def _curve_callback(log_every: int, total: int, curve: list, t0: float, c0: float, quiet: bool):
    from stable_baselines3.common.callbacks import BaseCallback

    class Curve(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.succ: deque[float] = deque(maxlen=100)
            self.rets: deque[float] = deque(maxlen=100)
            self.errs: deque[float] = deque(maxlen=100)
            self.next = log_every

        def _on_step(self) -> bool:
            for done, info in zip(self.locals["dones"], self.locals["infos"], strict=True):
                if done:
                    self.succ.append(float(info.get("is_success", False)))
                    if "episode" in info:
                        self.rets.append(float(info["episode"]["r"]))
                    if info.get("rms_error") is not None:
                        self.errs.append(float(info["rms_error"]))
            n = self.num_timesteps
            if n >= self.next:
                self.next += log_every
                row = {"steps": int(n), "wall_s": round(time.perf_counter() - t0, 1),
                       "success_last_100": round(float(np.mean(self.succ)), 3) if self.succ else None,
                       "return_last_100": round(float(np.mean(self.rets)), 2) if self.rets else None,
                       "rms_error_last_100": round(float(np.mean(self.errs)), 5) if self.errs else None}
                curve.append(row)
                if not quiet:
                    print(f"[{n:>8d}/{total}] success {row['success_last_100']}  return {row['return_last_100']}  "
                          f"rms {row['rms_error_last_100']}  {row['wall_s']:.0f} s wall, "
                          f"{time.process_time() - c0:.0f} s CPU", flush=True)
            return True

    return Curve()


def evaluate_agent(agent: Any, env_id: str, robot: str, n: int, seed: int, env_kwargs: dict[str, Any]) -> dict:
    """Episodes ``seed`` ... ``seed + n - 1`` of a torque policy (``predict(obs) -> (Nm, _)``, ``reset()``) on
    ``env_id`` with physical torque actions: the summary of ``franka_vs_gym.evaluate`` (without its per-episode
    list), plus the tracking task's mean RMS error."""
    import math

    import franka_vs_gym

    out = franka_vs_gym.evaluate(agent, env_id, n, seed, env_kwargs=dict(
        env_kwargs, robot=robot, action_type="torque", action_scale="physical", clip_actions=True))
    episodes = out.pop("episodes")
    out["seed"] = seed
    if math.isnan(out["mean_time_to_converge"]):
        out["mean_time_to_converge"] = None
    if env_id == "FrankaTorqueTracking-v0":
        rms = [e["rms_error"] for e in episodes if e.get("rms_error") is not None]
        out["mean_rms_error"] = float(np.mean(rms)) if rms else None  # (episodes that ended by a failure excluded)
    return out


class _Base:
    """The base alone (zero residual) as a policy, for the sidecar's comparison."""

    def __init__(self, env_id: str, model: Any, robot: str, env_kwargs: dict[str, Any]) -> None:
        from franka_vs_gym.envs.torque_agent import ResidualBase

        self.b = ResidualBase(env_id, model, robot, env_kwargs=env_kwargs)

    def reset(self) -> None:
        self.b.reset()

    def predict(self, obs: dict[str, Any], *a: Any, **k: Any) -> tuple[np.ndarray, None]:
        return self.b.combine(self.b.torque(obs), np.zeros(7)).astype(np.float32), None


def train(env_id: str, robot: str, seed: int, out: Path, timesteps: int = 300_000, model: str | None = None,
          randomize: bool = False, init: str | Path | None = None, n_envs: int = 8, eval_episodes: int = 100,
          eval_seed: int = 10_000, other_robot: bool = True, log_every: int = 20_000, threads: int = 1,
          learning_rate: float | None = None, quiet: bool = False, command: str | None = None,
          force: bool = False) -> dict[str, Any]:
    """Train (or, with ``init`` = an agent zip, fine-tune) a residual PPO agent; returns its sidecar dict (also
    written to ``out.json`` beside ``out.zip``).

    ``model``: the plant model the agent is trained on (the env's ``model``: None = the robot's default, or a
    model file such as ``fit``'s calibrated.json); the agent's base uses the same model. ``randomize``: train with
    :data:`RANDOMIZATION`. ``eval_episodes``: held-out episodes (seeds ``eval_seed``...) on the nominal env of that
    plant model, on ``robot`` and (``other_robot``, default model) on the other robot."""
    import torch

    torch.set_num_threads(max(1, int(threads)))
    from stable_baselines3 import PPO
    from stable_baselines3.common.monitor import Monitor
    from stable_baselines3.common.vec_env import DummyVecEnv

    from franka_vs_gym.envs.torque_agent import RESIDUAL_FRACTION, TorqueAgentPolicy, make_residual_env

    if env_id not in ENV_IDS:
        raise ValueError(f"env_id must be one of {ENV_IDS}, got {env_id!r}")
    if robot not in ROBOTS:
        raise ValueError(f"robot must be one of {ROBOTS}, got {robot!r}")
    out = Path(out)
    if out.suffix == ".zip":
        out = out.with_suffix("")
    zip_path, meta_path = out.with_suffix(".zip"), out.with_suffix(".json")
    if zip_path.exists() and not force:
        raise FileExistsError(f"{zip_path} exists; pass force=True (--force) to overwrite it")
    if int(timesteps) < 1:
        raise ValueError(f"timesteps must be >= 1, got {timesteps}")
    env_kwargs: dict[str, Any] = {} if model is None else {"model": str(model)}
    train_kwargs = dict(env_kwargs, **(RANDOMIZATION if randomize else {}))
    t0, c0 = time.perf_counter(), time.process_time()
    load0 = [round(x, 2) for x in os.getloadavg()]
    env = DummyVecEnv([lambda: Monitor(make_residual_env(env_id, robot=robot, **train_kwargs)) for _ in range(n_envs)])
    env.seed(seed)
    hp = dict(PPO_KWARGS)
    if learning_rate is not None:
        hp["learning_rate"] = float(learning_rate)
    if init is not None:
        agent = PPO.load(str(Path(init).with_suffix(".zip")), env=env, device="cpu", seed=seed,
                         custom_objects={"learning_rate": hp["learning_rate"]})
    else:
        agent = PPO("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **hp)
    curve: list[dict] = []
    agent.learn(total_timesteps=int(timesteps), callback=_curve_callback(log_every, int(timesteps), curve, t0, c0,
                                                                          quiet))
    train_wall, train_cpu = time.perf_counter() - t0, time.process_time() - c0
    out.parent.mkdir(parents=True, exist_ok=True)
    agent.save(str(zip_path))
    env.close()
    structure = ("residual PPO: torque = base(obs; the agent's plant model) + residual * "
                 f"{RESIDUAL_FRACTION} x the env's torque action scale, clipped to tau_max; base = "
                 + ("computed torque (ComputedTorquePolicy defaults)" if env_id == "FrankaTorqueTracking-v0" else
                    "scripted IBVS joint velocities tracked by M(q) 30 (dq_ibvs - dq) + C dq + F(dq)")
                 + "; the network learns the residual only")
    from franka_vs_gym.envs.torque_agent import LAYOUTS

    meta: dict[str, Any] = {
        "algo": "ppo", "env_id": env_id, "robot": robot, "env_kwargs": env_kwargs, "action_type": "torque",
        "action_scale": None, "observation_layout": LAYOUTS[env_id], "structure": structure,
        "residual_fraction": RESIDUAL_FRACTION,
        "train_env_kwargs": train_kwargs, "randomize": bool(randomize), "init": None if init is None else str(init),
        "timesteps": int(timesteps), "seed": int(seed), "n_envs": int(n_envs), "hyper_parameters": hp,
        "train_time_s": round(train_wall, 1), "train_cpu_s": round(train_cpu, 1), "torch_threads": int(threads),
        "load_at_start": load0, "command": command or "train_torque.train(...)", "training_curve": curve}
    meta_path.write_text(json.dumps(meta, indent=2))
    if eval_episodes > 0:
        pol = TorqueAgentPolicy.load(zip_path)
        meta["evaluation"] = evaluate_agent(pol, env_id, robot, eval_episodes, eval_seed, env_kwargs)
        meta["evaluation_base_alone"] = evaluate_agent(_Base(env_id, model, robot, env_kwargs), env_id, robot,
                                                       eval_episodes, eval_seed, env_kwargs)
        if randomize:
            meta["evaluation_randomized"] = evaluate_agent(pol, env_id, robot, eval_episodes, eval_seed,
                                                           dict(env_kwargs, **RANDOMIZATION))
            meta["evaluation_randomized_base_alone"] = evaluate_agent(
                _Base(env_id, model, robot, env_kwargs), env_id, robot, eval_episodes, eval_seed,
                dict(env_kwargs, **RANDOMIZATION))
        if other_robot and model is None:
            other = "fr3" if robot == "fer" else "fer"
            pol_o = TorqueAgentPolicy.load(zip_path, plant_model=None, robot=other)
            meta["evaluation_other_robot"] = evaluate_agent(pol_o, env_id, other, eval_episodes, eval_seed, {}) | {
                "robot": other, "note": "the same network; its base built on that robot's default model"}
        meta["total_time_s"] = round(time.perf_counter() - t0, 1)
        meta_path.write_text(json.dumps(meta, indent=2))
        if not quiet:
            ev = meta["evaluation"]
            print(f"evaluation over {eval_episodes} held-out episodes: success {ev['success_rate']:.2f} (base alone "
                  f"{meta['evaluation_base_alone']['success_rate']:.2f})", flush=True)
    return meta


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env-id", default="FrankaTorqueTracking-v0", choices=ENV_IDS)
    p.add_argument("--robot", default="fer", choices=ROBOTS)
    p.add_argument("--timesteps", type=int, default=300_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--model", default=None, help="plant model file (default: the robot's default model)")
    p.add_argument("--randomize", action="store_true", help="train with the env's dynamics randomisation")
    p.add_argument("--init", default=None, help="an agent zip to fine-tune from")
    p.add_argument("--n-envs", type=int, default=8)
    p.add_argument("--eval-episodes", type=int, default=100)
    p.add_argument("--eval-seed", type=int, default=10_000)
    p.add_argument("--log-every", type=int, default=20_000)
    p.add_argument("--learning-rate", type=float, default=None)
    p.add_argument("--out", required=True, help="output path without .zip")
    p.add_argument("--force", action="store_true")
    p.add_argument("--smoke", action="store_true", help="512 steps, 2 evaluation episodes")
    a = p.parse_args(argv)
    try:
        train(a.env_id, a.robot, a.seed, Path(a.out), 512 if a.smoke else a.timesteps, a.model, a.randomize,
              a.init, a.n_envs, 2 if a.smoke else a.eval_episodes, a.eval_seed, log_every=256 if a.smoke else
              a.log_every, learning_rate=a.learning_rate, command="python " + " ".join(sys.argv), force=a.force)
    except (ValueError, FileExistsError, FileNotFoundError) as e:
        print(f"train_torque: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
