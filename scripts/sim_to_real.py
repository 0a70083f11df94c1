#!/usr/bin/env python
"""Sim to real, end to end, through libfranka's protocol: on seeded "real robots" (lock-step ``franka-vs serve
--truth`` servers with a hidden payload, extra friction and a tilted mounting), record a designed excitation with
pylibfranka, calibrate with ``franka-vs fit --add auto``, and run the torque controllers on FrankaTorqueTracking-v0's
episodes with the default, the calibrated (alone and with the motors' published armature) and the true plant's model:
tracking error per case and the gap recovered (franka_vs_gym.fci.sim_to_real; docs/sim_to_real.md).

    python scripts/sim_to_real.py --out runs/sim_to_real [--robots 0,1,2] [--episodes 3] [--duration 20]

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

from franka_vs_gym.fci.sim_to_real import CONTROLLERS, MODELS, check_host, design_excitation, run_robot
from franka_vs_gym.io import atomic_write


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


def figure(results: list[dict], controllers: tuple[str, ...], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(controllers), figsize=(5.5 * len(controllers), 4), squeeze=False)
    colors = {"default": "#c44e52", "calibrated": "#4c72b0", "calibrated+motors": "#8172b2", "truth": "#55a868"}
    w = 0.8 / len(MODELS)
    for ax, c in zip(axes[0], controllers, strict=True):
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
    out.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()

    def say(s: str) -> None:
        print(f"[{time.perf_counter() - t0:6.0f} s] {s}", flush=True)

    say(f"designing the excitation ({args.duration:g} s, franka-vs excite)")
    script = design_excitation(out / "excitation", args.duration, args.evaluations)
    seeds = list(range(args.episode_seed, args.episode_seed + args.episodes))
    results = []
    for s in robots:
        results.append(run_robot(s, out / f"robot_{s}", args.host, script, seeds, controllers, say=say))
        atomic_write(out / "results.json", json.dumps({"robots": results, "episode_seeds": seeds,
                                                        "excitation_s": args.duration}, indent=1), force=True)
    lines = table(results, controllers)
    print("\n".join(lines))
    figure(results, controllers, out / "sim_to_real.png")
    say(f"wrote {out / 'results.json'} and {out / 'sim_to_real.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
