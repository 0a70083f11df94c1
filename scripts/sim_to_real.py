#!/usr/bin/env python
"""Sim to real, end to end, through libfranka's protocol: on seeded "real robots" (lock-step ``franka-vs serve
--truth`` servers with a hidden payload, extra friction and a tilted mounting), record a designed excitation with
pylibfranka, calibrate with ``franka-vs fit --add auto``, and run the torque controllers on FrankaTorqueTracking-v0's
episodes with the default, the calibrated (alone and with the motors' published armature) and the true plant's model:
tracking error per case and the gap recovered (franka_vs_gym.fci.sim_to_real; docs/sim_to_real.md).

    python scripts/sim_to_real.py --out runs/sim_to_real [--robots 0,1,2] [--episodes 3] [--duration 20] [--agents]

``--agents`` adds the torque agents (baselines/train_torque.py's residual PPO on computed torque), ``--agent-seeds``
training seeds each, all played through pylibfranka on every robot: trained from scratch for ``--agent-steps`` steps
on the default plant, on the calibrated model (per robot) and on the true plant's model (per robot); and the
randomised one, the shipped ``torque_tracking_fer`` agent (600 k steps under the envs' dynamics randomisation)
fine-tuned for ``--agent-steps`` more steps under that randomisation per seed.

Writes OUT/results.json, OUT/sim_to_real.png and per robot OUT/robot_<seed>/ (truth, true model, recording,
calibrated model); prints progress and the table.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from franka_vs_gym.fci.sim_to_real import (
    AGENT_KINDS,
    CONTROLLERS,
    MODELS,
    check_host,
    design_excitation,
    run_robot,
    stop_on_signals,
)
from franka_vs_gym.io import atomic_write

ROOT = Path(__file__).resolve().parents[1]


def _train_torque():
    """baselines/train_torque.py (a script of the source tree, not an installed module)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("train_torque", ROOT / "baselines" / "train_torque.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


class AgentTrainer:
    """Trains the study's torque agents, ``kind`` x training seed: from scratch on the plant of its kind (default,
    calibrated, true), or (randomised) a fine-tune of the shipped randomised FER agent under the randomisation; the
    default and randomised ones once for all robots, the calibrated and true-plant ones per robot. Returns
    ``{kind: [zip, ...]}`` for run_robot."""

    def __init__(self, out: Path, seeds: int, steps: int, init: Path, say) -> None:
        self.out, self.seeds, self.steps, self.init, self.say = out, seeds, steps, init, say
        self.tt = _train_torque()
        self.shared: dict[str, list[str]] = {}
        self.meta: dict[str, list[dict]] = {}

    def _train(self, kind: str, tag: str, model: str | None, randomize: bool) -> list[str]:
        init = self.init if randomize else None
        zips = []
        for s in range(self.seeds):
            dest = self.out / f"{tag}_s{s}"
            t = time.perf_counter()
            m = self.tt.train("FrankaTorqueTracking-v0", "fer", s, dest, timesteps=self.steps, model=model,
                              randomize=randomize, init=init, eval_episodes=0, log_every=self.steps,
                              quiet=True, force=True, command=f"scripts/sim_to_real.py --agents ({tag}, seed {s})")
            self.meta.setdefault(tag, []).append({k: m[k] for k in ("seed", "timesteps", "train_time_s",
                                                                     "train_cpu_s", "training_curve")})
            how = "fine-tuned" if init is not None else "trained"
            self.say(f"agent {tag} seed {s}: {how} {self.steps} steps in {time.perf_counter() - t:.0f} s "
                     f"({m['train_cpu_s']:.0f} s CPU)")
            zips.append(str(dest.with_suffix(".zip")))
        return zips

    def prepare_shared(self) -> None:
        self.shared["default"] = self._train("default", "default", None, False)
        self.shared["randomized"] = self._train("randomized", "randomized", None, True)

    def __call__(self, robot_seed: int):
        def agents(models: dict) -> dict[str, list[str]]:
            cal = self._train("calibrated", f"robot_{robot_seed}_calibrated", models["calibrated"], False)
            tru = self._train("truth", f"robot_{robot_seed}_truth", models["truth"], False)
            return {"default": self.shared["default"], "calibrated": cal, "randomized": self.shared["randomized"],
                    "truth": tru}
        return agents


def table(results: list[dict], controllers: tuple[str, ...]) -> list[str]:
    def pct(g):
        return "n/a (default < 2 x truth)" if g is None else f"{100 * g:.0f} %"

    lines = ["| robot | controller | rms error (rad): default model | calibrated | calibrated + motors | "
             "true plant's | gap recovered: calibrated | calibrated + motors | success (of the episodes, per model) | "
             "fitted effects |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for c in controllers:
            e = [r["runs"][f"{c}/{m}"]["rms_error"] for m in MODELS]
            s = " / ".join(str(r["runs"][f"{c}/{m}"]["success"]) for m in MODELS)
            n = len(r["runs"][f"{c}/default"]["episodes"])
            lines.append(f"| {r['seed']} | {c.replace('_', ' ')} | " + " | ".join(f"{x:.4f}" for x in e) + " | "
                         f"{pct(r['runs'][f'{c}/gap_recovered'])} | {pct(r['runs'][f'{c}/gap_recovered_motors'])} | "
                         f"{s} of {n} | {', '.join(r['fit']['effects'] or [])} |")
    return lines


def agent_table(results: list[dict]) -> list[str]:
    def pct(g):
        return "n/a" if g is None else f"{100 * g:.0f} %"

    lines = ["| robot | agent trained on | rms error (rad), mean of the seeds | per training seed | "
             "success (episodes) | gap recovered |", "|---|---|---|---|---|---|"]
    for r in results:
        for k in AGENT_KINDS:
            a = r["runs"].get(f"agent/{k}")
            if a is None:
                continue
            g = r["runs"].get(f"agent/gap_recovered_{k}", "")
            lines.append(f"| {r['seed']} | {k} | {a['rms_error']:.4f} | "
                         + ", ".join(f"{x:.4f}" for x in a["rms_error_per_seed"])
                         + f" | {a['success']} of {a['episodes_total']} | {pct(g) if g != '' else ''} |")
    return lines


def figure(results: list[dict], controllers: tuple[str, ...], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with_agents = any("agent/default" in r["runs"] for r in results)
    n = len(controllers) + int(with_agents)
    fig, axes = plt.subplots(1, n, figsize=(5.5 * n, 4), squeeze=False)
    colors = {"default": "#c44e52", "calibrated": "#4c72b0", "calibrated+motors": "#8172b2", "truth": "#55a868"}
    w = 0.8 / len(MODELS)
    for ax, c in zip(axes[0][:len(controllers)], controllers, strict=True):
        x = np.arange(len(results))
        for k, m in enumerate(MODELS):
            v = [1e3 * r["runs"][f"{c}/{m}"]["rms_error"] for r in results]
            ax.bar(x + (k - (len(MODELS) - 1) / 2) * w, v, w, label=f"{m} model", color=colors[m])
        for i, r in enumerate(results):
            g, gm = r["runs"][f"{c}/gap_recovered"], r["runs"][f"{c}/gap_recovered_motors"]
            top = 1e3 * max(r["runs"][f"{c}/{m}"]["rms_error"] for m in MODELS)
            txt = " / ".join("n/a" if x is None else f"{100 * x:.0f} %" for x in (g, gm))
            ax.text(i, top * 1.15, txt, ha="center", fontsize=8)
        ax.set_xticks(x, [f"robot {r['seed']}" for r in results])
        ax.set_ylabel("RMS tracking error (mrad)")
        ax.set_title(f"{c.replace('_', ' ')}: gap recovered (calibrated / + motors)", fontsize=10)
        ax.set_yscale("log")
        ax.set_ylim(top=ax.get_ylim()[1] * 2.5)
    if with_agents:
        ax = axes[0][-1]
        ak = [k for k in AGENT_KINDS if all(f"agent/{k}" in r["runs"] for r in results)]
        acol = {"default": "#c44e52", "calibrated": "#4c72b0", "randomized": "#dd8452", "truth": "#55a868"}
        wa = 0.8 / len(ak)
        x = np.arange(len(results))
        for k, kind in enumerate(ak):
            off = (k - (len(ak) - 1) / 2) * wa
            v = [1e3 * r["runs"][f"agent/{kind}"]["rms_error"] for r in results]
            ax.bar(x + off, v, wa, color=acol[kind], label=f"agent: {kind}")
            for i, r in enumerate(results):  # the training seeds
                ps = r["runs"][f"agent/{kind}"]["rms_error_per_seed"]
                ax.plot([i + off] * len(ps), [1e3 * p for p in ps], "k.", ms=3)
        for i, r in enumerate(results):
            g = r["runs"].get("agent/gap_recovered_calibrated")
            top = 1e3 * max(r["runs"][f"agent/{k}"]["rms_error"] for k in ak)
            ax.text(i, top * 1.15, "n/a" if g is None else f"{100 * g:.0f} %", ha="center", fontsize=8)
        ax.set_xticks(x, [f"robot {r['seed']}" for r in results])
        ax.set_ylabel("RMS tracking error (mrad)")
        ax.set_title("torque agents (dots: training seeds): gap recovered, calibrated", fontsize=10)
        ax.set_yscale("log")
        ax.set_ylim(top=ax.get_ylim()[1] * 8)
        ax.legend(fontsize=7, loc="upper center", ncol=len(ak))
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(MODELS), fontsize=9)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="output folder (must not exist unless --force)")
    ap.add_argument("--robots", default="0,1,2", help="seeds of the robots (their hidden truth), comma-separated")
    ap.add_argument("--episodes", type=int, default=3, help="FrankaTorqueTracking-v0 episodes per case (default 3)")
    ap.add_argument("--episode-seed", type=int, default=10_000, help="first episode's seed (default 10000)")
    ap.add_argument("--duration", type=float, default=20.0, help="excitation length, s (default 20)")
    ap.add_argument("--evaluations", type=int, default=200, help="excitation design evaluations (default 200)")
    ap.add_argument("--controllers", default=",".join(CONTROLLERS))
    ap.add_argument("--host", default="127.0.0.71", help="loopback address of the servers (default 127.0.0.71)")
    ap.add_argument("--force", action="store_true", help="write into an existing output folder")
    ap.add_argument("--agents", action="store_true", help="also train and play the torque agents (see above)")
    ap.add_argument("--agent-seeds", type=int, default=3, help="training seeds per agent kind (default 3)")
    ap.add_argument("--agent-steps", type=int, default=30_000, help="training steps per agent (default 30000)")
    ap.add_argument("--agent-init", default=None, help="the randomised agent zip the randomised kind is fine-tuned "
                    "from (default the shipped torque_tracking_fer)")
    args = ap.parse_args()
    try:
        robots = [int(s) for s in args.robots.split(",") if s.strip()]
    except ValueError:
        ap.error(f"--robots must be integers separated by commas, got {args.robots!r}")
    controllers = tuple(c for c in args.controllers.split(",") if c)
    bad = [c for c in controllers if c not in CONTROLLERS]
    if bad or not controllers:
        ap.error(f"--controllers: choose from {','.join(CONTROLLERS)}")
    if not robots or args.episodes < 1 or not 4 <= args.duration <= 120:
        ap.error("need at least one robot, --episodes >= 1 and --duration in [4, 120] s")
    try:
        check_host(args.host)
    except Exception as e:  # (UserError)
        ap.error(str(e))
    out = Path(args.out)
    if out.exists() and not args.force:
        ap.error(f"--out {out} exists; choose another folder or pass --force")
    if args.agents and (args.agent_seeds < 1 or args.agent_steps < 1):
        ap.error("--agent-seeds and --agent-steps must be >= 1")
    init = None
    if args.agents:
        from franka_vs_gym.policies import agent_path

        try:
            init = Path(args.agent_init) if args.agent_init else agent_path("torque_tracking_fer")
        except ValueError as e:
            ap.error(str(e))
        if not init.with_suffix(".zip").is_file():
            ap.error(f"--agent-init {init}: no such agent zip")
    out.mkdir(parents=True, exist_ok=True)
    stop_on_signals()  # (SIGTERM ends the truth server and the clients too)

    t0 = time.perf_counter()

    def say(s: str) -> None:
        print(f"[{time.perf_counter() - t0:6.0f} s] {s}", flush=True)

    say(f"designing the excitation ({args.duration:g} s, franka-vs excite)")
    script = design_excitation(out / "excitation", args.duration, args.evaluations)
    seeds = list(range(args.episode_seed, args.episode_seed + args.episodes))
    trainer = None
    if args.agents:
        trainer = AgentTrainer(out / "agents", args.agent_seeds, args.agent_steps, init, say)
        say(f"training the default-plant and randomised agents ({args.agent_seeds} seeds x {args.agent_steps} "
            "steps each)")
        trainer.prepare_shared()
    results = []
    for s in robots:
        results.append(run_robot(s, out / f"robot_{s}", args.host, script, seeds, controllers, say=say,
                                 agents=None if trainer is None else trainer(s)))
        atomic_write(out / "results.json", json.dumps({"robots": results, "episode_seeds": seeds,
                                                        "excitation_s": args.duration,
                                                        "agents": None if trainer is None else trainer.meta},
                                                       indent=1), force=True)
    lines = table(results, controllers)
    if trainer is not None:
        lines += ["", *agent_table(results)]
    print("\n".join(lines))
    figure(results, controllers, out / "sim_to_real.png")
    say(f"wrote {out / 'results.json'} and {out / 'sim_to_real.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
