"""Train the pixel agent of FrankaIBVS-v0: the wrist camera image (with q, dq) in, joint velocities out, by DAgger.

    python baselines/train_pixels.py --out runs/pixels/ibvs_pixels          # about an hour on one core
    python baselines/train_pixels.py --smoke --out /tmp/pixels_smoke        # a minute: the pipeline runs

The student is a stable-baselines3 PPO ``MultiInputPolicy`` whose features extractor is
:class:`franka_vs_gym.envs.pixels.PixelServoExtractor`; it sees only ``observation_type="image"`` keys (the
``--image-width`` x ``--image-height`` camera image, q, dq). Its weights are trained by imitation (DAgger, Ross,
Gordon and Bagnell, AISTATS 2011): robots of the native vector env (:class:`~franka_vs_gym.envs.vector.
FrankaVectorEnv`, ``observation_type="features+image"``) are driven by the student (iteration 0: by the teacher;
iteration i: each step by the teacher with probability ``--beta`` ** i), every visited state is labelled with the
action of the scripted IBVS teacher (``franka_vs_gym.policies.IBVSPolicy`` in the env's normalized action space,
which reads the privileged features), the labelled states are aggregated and the student regresses them (the
squared action error, plus the error of its corner and depth estimates against the true ones; the action and
corner errors relative to the label's size with a floor, so that the states near the goal, where success is
decided, count). The features are labels at training time only.

The clock starts before anything is made. Every ``--eval-every`` iterations the student alone (deterministic) runs
the held-out episodes (seeds ``--eval-seed`` ... ``--eval-seed + --eval-episodes - 1``; training never resets with
these) on the same vector env; training stops when the success rate reaches ``--stop``, after ``--iterations`` or
at ``--budget`` seconds. The best evaluated student is saved as ``<out>.zip`` with its JSON sidecar
``<out>.json`` (env kwargs, action scale, observation layout, training record and curve), confirmed with
``franka_vs_gym.evaluate`` on single environments (outside the clock), and its curve is drawn to
``<out>_curve.png``.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

# floors of the relative errors (see Student.train): an action of norm 0.02 (normalized units), a feature error of
# 0.02 (twice the success threshold)
ACTION_FLOOR, CORNER_FLOOR = 0.02, 0.02


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--env-id", default="FrankaIBVS-v0")
    p.add_argument("--out", default="runs/pixels/ibvs_pixels", help="output path without .zip")
    p.add_argument("--image-width", type=int, default=64)
    p.add_argument("--image-height", type=int, default=48)
    p.add_argument("--n-envs", type=int, default=16, help="robots of the vector env")
    p.add_argument("--iterations", type=int, default=40, help="DAgger iterations at most")
    p.add_argument("--teacher-steps", type=int, default=500, help="vector steps of iteration 0 (teacher driving)")
    p.add_argument("--steps", type=int, default=250, help="vector steps of each later iteration")
    p.add_argument("--updates", type=int, default=250, help="gradient steps after each iteration")
    p.add_argument("--batch-size", type=int, default=128)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--lr-decay", type=float, default=0.93, help="learning rate of iteration i: lr * decay ** i")
    p.add_argument("--lr-min", type=float, default=0.1, help="... but at least lr * lr-min")
    p.add_argument("--beta", type=float, default=0.5, help="teacher share of iteration i is beta ** i")
    p.add_argument("--keypoints", type=int, default=16)
    p.add_argument("--max-samples", type=int, default=150_000, help="labelled states kept (oldest dropped)")
    p.add_argument("--eval-every", type=int, default=3, help="evaluate every N iterations")
    p.add_argument("--eval-episodes", type=int, default=100)
    p.add_argument("--eval-seed", type=int, default=10_000)
    p.add_argument("--stop", type=float, default=0.95, help="stop at this held-out success rate")
    p.add_argument("--budget", type=float, default=3600.0, help="wall-clock seconds of training at most")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch threads (keep 1 on a shared machine)")
    p.add_argument("--batch-threads", type=int, default=1, help="threads of the vector env's physics batch")
    p.add_argument("--force", action="store_true", help="overwrite existing outputs")
    p.add_argument("--smoke", action="store_true", help="a tiny run (the pipeline, not a useful agent)")
    return p


class Dataset:
    """The aggregated labelled states (a ring buffer of ``capacity``)."""

    def __init__(self, capacity: int, h: int, w: int) -> None:
        self.image = np.zeros((capacity, h, w, 3), np.uint8)
        self.vec = {k: np.zeros((capacity, n), np.float32) for k, n in
                    (("q", 7), ("dq", 7), ("action", 7), ("features", 8), ("depth", 4))}
        self.capacity, self.size, self.head = capacity, 0, 0

    def add(self, image: np.ndarray, **vec: np.ndarray) -> None:
        n = len(image)
        idx = (self.head + np.arange(n)) % self.capacity
        self.image[idx] = image
        for k, v in vec.items():
            self.vec[k][idx] = v
        self.head = int((self.head + n) % self.capacity)
        self.size = min(self.capacity, self.size + n)

    def sample(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        idx = rng.integers(0, self.size, n)
        return self.image[idx], {k: v[idx] for k, v in self.vec.items()}


class Student:
    """The SB3 PPO model whose policy mean is trained by regression."""

    def __init__(self, env_id: str, env_kwargs: dict[str, Any], keypoints: int, seed: int, lr: float) -> None:
        import gymnasium as gym
        import torch
        from stable_baselines3 import PPO

        from franka_vs_gym.envs.pixels import PixelServoExtractor

        env = gym.make(env_id, observation_type="image", **env_kwargs)  # the agent's spaces (never stepped)
        u = env.unwrapped
        self.s_star = np.asarray(u.features_desired, np.float64)
        self.z_star = float(np.mean(u.depth_desired))
        self.action_scale = np.asarray(u.action_scale, np.float64)
        self.model = PPO("MultiInputPolicy", env, seed=seed, device="cpu", verbose=0, policy_kwargs={
            "features_extractor_class": PixelServoExtractor,
            "features_extractor_kwargs": {"goal_features": self.s_star.tolist(), "goal_depth": self.z_star,
                                          "keypoints": keypoints},
            "net_arch": {"pi": [128, 128], "vf": [64, 64]}, "log_std_init": -2.0})
        env.close()
        self.model.env = None  # (the spaces are kept; nothing steps through the model)
        pol = self.model.policy
        self.fe = pol.features_extractor
        self.params = (list(self.fe.parameters()) + list(pol.mlp_extractor.policy_net.parameters())
                       + list(pol.action_net.parameters()))
        self.opt = torch.optim.Adam(self.params, lr=lr)

    def forward(self, image: np.ndarray, q: np.ndarray, dq: np.ndarray):
        import torch

        img = torch.as_tensor(image).permute(0, 3, 1, 2).float() / 255.0
        feats, s, z = self.fe.parts(img, torch.as_tensor(q), torch.as_tensor(dq))
        pol = self.model.policy
        return pol.action_net(pol.mlp_extractor.forward_actor(feats)), s, z

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """Deterministic actions (N, 7) in [-1, 1] for the vector env's observations (what ``predict`` returns)."""
        import torch

        with torch.no_grad():
            mu = self.forward(obs["image"], obs["q"], obs["dq"])[0].numpy()
        return np.clip(mu, -1.0, 1.0).astype(np.float32)

    def train(self, data: Dataset, rng: np.random.Generator, updates: int, batch: int) -> dict[str, float]:
        """``updates`` Adam steps on batches of the aggregate. The action and corner errors are relative: divided by
        (squared size of the label + a floor), so the states close to the goal, where success is decided (feature
        error < 0.01), weigh as much as the far ones; the depth error is divided by its label variance."""
        import torch

        n = data.size
        var_z = float(np.var(data.vec["depth"][:n]) + 1e-8)
        s_star = torch.as_tensor(self.s_star, dtype=torch.float32)
        totals = {"action": 0.0, "features": 0.0, "depth": 0.0, "near": 0.0}
        near_n = 0
        for _ in range(updates):
            img, v = data.sample(rng, batch)
            a, f, z_true = (torch.as_tensor(v[k]) for k in ("action", "features", "depth"))
            mu, s, z = self.forward(img, v["q"], v["dq"])
            e2 = ((f - s_star) ** 2).sum(1)
            da = ((mu - a) ** 2).sum(1)
            ds = ((s - f) ** 2).sum(1)
            dz = ((z - z_true) ** 2).mean(1)
            loss = ((da / ((a * a).sum(1) + ACTION_FLOOR ** 2)).mean() + (ds / (e2 + CORNER_FLOOR ** 2)).mean()
                    + dz.mean() / var_z)
            self.opt.zero_grad()
            loss.backward()
            self.opt.step()
            with torch.no_grad():
                totals["action"] += da.mean().item() / 7
                totals["features"] += ds.mean().item() / 8
                totals["depth"] += dz.mean().item()
                near = e2 < 0.03 ** 2
                totals["near"] += ds[near].sum().item() / 8
                near_n += int(near.sum())
        # root mean squares over the updates: action (normalized units), corners (normalized coordinates), depth
        # (m), and the corners of the states within 0.03 of the goal
        out = {k: math.sqrt(totals[k] / max(updates, 1)) for k in ("action", "features", "depth")}
        out["near"] = math.sqrt(totals["near"] / near_n) if near_n else math.nan
        return out


def _rows(obs: dict[str, np.ndarray], i: int) -> dict[str, np.ndarray]:
    return {k: v[i] for k, v in obs.items()}


def _final(info: dict[str, Any], i: int) -> dict[str, Any]:
    final = info["final_info"]
    return {k: v[i] for k, v in final.items() if not k.startswith("_") and final["_" + k][i]}


def collect(venv: Any, obs: dict[str, np.ndarray], student: Student, teacher: Any, data: Dataset, steps: int,
            beta: float, rng: np.random.Generator) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """``steps`` vector steps: each robot acts as the teacher with probability beta, else as the student; every
    visited state is stored with the teacher's action."""
    n = venv.num_envs
    stats = {"episodes": 0, "successes": 0}
    for _ in range(steps):
        label = np.stack([teacher.predict(_rows(obs, i))[0] for i in range(n)]).astype(np.float32)
        data.add(obs["image"], q=obs["q"], dq=obs["dq"], action=label, features=obs["features"],
                 depth=obs["feature_depth"])
        act = label if beta >= 1.0 else student.act(obs)
        if 0.0 < beta < 1.0:
            use = rng.random(n) < beta
            act = np.where(use[:, None], label, act)
        obs, _, term, trunc, info = venv.step(act)
        for i in np.flatnonzero(term | trunc):
            stats["episodes"] += 1
            stats["successes"] += int(bool(_final(info, i).get("is_success", False)))
    return obs, stats


def evaluate_student(venv: Any, student: Student, seeds: list[int]) -> dict[str, Any]:
    """The first episode of each held-out seed, the student alone (deterministic), num_envs robots at a time."""
    n = venv.num_envs
    success, t_conv, failures = [], [], {}
    for c in range(0, len(seeds), n):
        chunk = seeds[c:c + n]
        pad = chunk + [seeds[-1] + 1_000_000 + j for j in range(n - len(chunk))]  # unused robots of the last chunk
        obs, _ = venv.reset(seed=pad)
        done = np.zeros(n, dtype=bool)
        while not done[:len(chunk)].all():
            obs, _, term, trunc, info = venv.step(student.act(obs))
            for i in np.flatnonzero((term | trunc) & ~done):
                done[i] = True
                if i < len(chunk):
                    f = _final(info, i)
                    ok = bool(f.get("is_success", False))
                    success.append(ok)
                    t_conv.append(float(f.get("time", math.nan)) if ok else math.nan)
                    if f.get("failure"):
                        key = str(f["failure"]).split(":")[0]
                        failures[key] = failures.get(key, 0) + 1
    rate = float(np.mean(success))
    return {"success_rate": rate, "mean_time_to_converge": float(np.nanmean(t_conv)) if any(success) else None,
            "failures": failures}


def plot_curve(curve: list[dict[str, Any]], path: Path, force: bool, title: str, chosen: int | None = None) -> None:
    """Held-out success against labelled states and wall time; ``chosen``: the curve row of the saved agent
    (marked)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from franka_vs_gym.io import atomic_write

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=True)
    rates = [100 * r["success_rate"] for r in curve]
    for ax, key, label in ((axes[0], "samples", "labelled states (env steps)"),
                           (axes[1], "wall_min", "wall-clock time (min)")):
        ax.plot([r[key] for r in curve], rates, "o-", color="tab:blue")
        if chosen is not None:
            ax.plot([curve[chosen][key]], [rates[chosen]], "*", ms=16, color="tab:orange", label="saved agent")
        ax.axhline(90, color="tab:gray", ls="--", lw=1)
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("held-out success (%)")
    axes[0].set_ylim(-2, 106)
    if chosen is not None:
        axes[0].legend(loc="lower right")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=110), force=force, what="curve PNG")
    plt.close(fig)


def train(args: argparse.Namespace) -> dict[str, Any]:
    t0, c0, load0 = time.perf_counter(), time.process_time(), [round(x, 2) for x in os.getloadavg()]
    import torch

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    import franka_vs_gym
    from franka_vs_gym.envs.vector import FrankaVectorEnv
    from franka_vs_gym.envs.wrappers import IMAGE_LAYOUT, AgentPolicy
    from franka_vs_gym.io import atomic_write, check_output
    from franka_vs_gym.policies import IBVSPolicy

    if args.smoke:
        args.iterations, args.teacher_steps, args.steps, args.updates = 2, 20, 10, 5
        args.eval_every, args.eval_episodes, args.n_envs, args.max_samples = 1, 4, 4, 2000
    for name in ("n_envs", "iterations", "teacher_steps", "steps", "batch_size", "eval_every", "eval_episodes",
                 "max_samples", "keypoints", "threads", "batch_threads"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if not 0.0 <= args.beta <= 1.0:
        raise ValueError(f"--beta must be in [0, 1], got {args.beta}")
    out = Path(args.out)
    paths = {"zip": out.with_name(out.name + ".zip"), "json": out.with_name(out.name + ".json"),
             "png": out.with_name(out.name + "_curve.png")}
    for what, p in paths.items():
        check_output(p, args.force, what=f"{what} output")
    env_kwargs = {"image_width": args.image_width, "image_height": args.image_height}
    rng = np.random.default_rng(args.seed)
    student = Student(args.env_id, env_kwargs, args.keypoints, args.seed, args.lr)
    teacher = IBVSPolicy().with_action_scale(student.action_scale)
    venv = FrankaVectorEnv(args.env_id, args.n_envs, nthread=args.batch_threads, autoreset_mode="SameStep",
                           observation_type="features+image", **env_kwargs)
    data = Dataset(args.max_samples, args.image_height, args.image_width)
    held_out = [args.eval_seed + i for i in range(args.eval_episodes)]
    train_seed = 1_000_000 * (args.seed + 1)  # training resets: far from the held-out seeds
    obs, _ = venv.reset(seed=train_seed)
    curve: list[dict[str, Any]] = []
    best: tuple[float, Any] | None = None
    chosen = 0  # the curve row of the saved agent (the first best held-out success)
    reached: dict[str, float | None] = {"0.90": None, "0.95": None}
    print(f"DAgger on {args.env_id} from {args.image_width}x{args.image_height} images, {args.n_envs} robots, "
          f"torch threads {args.threads}, batch threads {args.batch_threads}", flush=True)
    eval_wall = 0.0
    for it in range(args.iterations):
        beta = args.beta ** it
        tc = time.perf_counter()
        obs, stats = collect(venv, obs, student, teacher, data, args.teacher_steps if it == 0 else args.steps,
                             beta, rng)
        t_collect = time.perf_counter() - tc
        for g in student.opt.param_groups:
            g["lr"] = args.lr * max(args.lr_min, args.lr_decay ** it)
        losses = student.train(data, rng, args.updates, args.batch_size)
        t_train = time.perf_counter() - tc - t_collect
        line = (f"iter {it:2d} beta {beta:.3f} samples {data.size:6d} wall {time.perf_counter() - t0:6.0f} s  "
                f"rollout success {stats['successes']}/{stats['episodes']}  rms action {losses['action']:.4f} "
                f"corners {losses['features']:.4f} (near the goal {losses['near']:.4f}) depth {losses['depth']:.4f}  "
                f"[collect {t_collect:.0f} s, train {t_train:.0f} s]")
        last = it == args.iterations - 1 or time.perf_counter() - t0 > args.budget
        if (it + 1) % args.eval_every == 0 or last:
            te = time.perf_counter()
            r = evaluate_student(venv, student, held_out)
            eval_wall += time.perf_counter() - te
            train_seed += args.n_envs
            obs, _ = venv.reset(seed=train_seed + 10_000 * (it + 1))
            wall = time.perf_counter() - t0
            row = {"iteration": it, "samples": collected(args, it),
                   "wall_s": round(wall, 1), "wall_min": round(wall / 60, 2),
                   "cpu_s": round(time.process_time() - c0, 1), **r, "rms": losses}
            curve.append(row)
            for g in reached:
                if reached[g] is None and r["success_rate"] >= float(g):
                    reached[g] = round(wall, 1)
            line += f"  | held-out success {r['success_rate']:.2f} failures {r['failures'] or 'none'}"
            if best is None or r["success_rate"] > best[0]:
                best = (r["success_rate"], copy.deepcopy(student.model.policy.state_dict()))
                chosen = len(curve) - 1
            print(line, flush=True)
            if r["success_rate"] >= args.stop:
                break
        else:
            print(line, flush=True)
        if last:
            break
    wall, cpu, load1 = time.perf_counter() - t0, time.process_time() - c0, [round(x, 2) for x in os.getloadavg()]
    venv.close()
    student.model.policy.load_state_dict(best[1])
    atomic_write(paths["zip"], lambda fh: student.model.save(fh), force=args.force, what="agent zip")
    kw = {"observation_type": "image", **env_kwargs}
    agent = AgentPolicy(student.model, student.action_scale.tolist(), args.env_id, kw, IMAGE_LAYOUT)
    r = franka_vs_gym.evaluate(agent, args.env_id, args.eval_episodes, args.eval_seed, env_kwargs=kw)
    summary = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
               for k, v in r.items() if k != "episodes"}
    print(f"confirmed with franka_vs_gym.evaluate ({args.eval_episodes} episodes, seeds {args.eval_seed}...): "
          f"success rate {r['success_rate']:.2f}, mean time to converge {r['mean_time_to_converge']:.2f} s, "
          f"failures {r['failures'] or 'none'}", flush=True)
    meta = {"algo": "ppo", "env_id": args.env_id, "env_kwargs": kw, "action_scale": student.action_scale.tolist(),
            "action_type": "joint_velocity", "observation_layout": IMAGE_LAYOUT, "seed": args.seed,
            "n_envs": args.n_envs,
            "training": {"method": "DAgger on the scripted IBVS teacher (labels only; the agent sees image, q, dq)",
                         "iterations": curve[-1]["iteration"] + 1, "samples": curve[-1]["samples"],
                         "saved_iteration": curve[chosen]["iteration"], "saved_samples": curve[chosen]["samples"],
                         "wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "eval_wall_s": round(eval_wall, 1),
                         "wall_s_to_0.90": reached["0.90"], "wall_s_to_0.95": reached["0.95"],
                         "cores": f"1 process: torch {args.threads} thread(s), physics batch {args.batch_threads} "
                                  f"thread(s), one MuJoCo EGL context", "cpu_count": os.cpu_count(),
                         "loadavg_start": load0, "loadavg_end": load1,
                         "hyperparameters": {k: getattr(args, k) for k in (
                             "teacher_steps", "steps", "updates", "batch_size", "lr", "lr_decay", "lr_min", "beta",
                             "keypoints", "max_samples")}},
            "train_time_s": round(wall, 1), "command": "python " + " ".join(sys.argv),
            "evaluation": summary | {"seed": args.eval_seed}, "curve": curve}
    atomic_write(paths["json"], json.dumps(meta, indent=2), force=args.force, what="agent JSON")
    plot_curve(curve, paths["png"], args.force,
               f"{args.env_id} from {args.image_width}x{args.image_height} images: DAgger student, held-out "
               f"success on {args.eval_episodes} episodes", chosen)
    print(f"saved {paths['zip']} ({paths['zip'].stat().st_size / 1e6:.2f} MB), {paths['json']}, {paths['png']}; "
          f"training {wall / 60:.1f} min wall, {cpu / 60:.1f} min CPU", flush=True)
    return meta


def collected(args: argparse.Namespace, it: int) -> int:
    """Labelled states gathered by the end of iteration ``it``."""
    return args.n_envs * (args.teacher_steps + it * args.steps)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        train(args)
    except (ValueError, FileExistsError) as e:
        print(f"train_pixels: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
