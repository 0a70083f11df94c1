#!/usr/bin/env python
"""Convergence study of the classical visual-servoing baselines on the simulated FER.

From N seeded random starts (camera up to 15 cm and 30 deg from the goal, tag in view), run IBVS and PBVS and
report the success rate, time to converge and final errors. Success: IBVS, every corner within 1 px of its goal;
PBVS, camera pose within 1 mm and 0.5 deg.

    python scripts/eval_servo.py [--n 100] [--features ideal|detect] [--kinds ibvs,pbvs] [--width W --height H]
                                 [--interaction CURRENT|DESIRED|MEAN] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np
from tqdm import tqdm

from franka_vs_gym.experiments.servo import run_servo
from franka_vs_gym.vision import CameraIntrinsics


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100, help="number of seeded starts (default 100)")
    ap.add_argument("--features", default="ideal", choices=["ideal", "detect"])
    ap.add_argument("--kinds", default="ibvs,pbvs")
    ap.add_argument("--duration", type=float, default=15.0, help="time limit per run, s")
    ap.add_argument("--interaction", default="MEAN", choices=["CURRENT", "DESIRED", "MEAN"],
                    help="IBVS interaction matrix (default MEAN)")
    ap.add_argument("--width", type=int, default=320, help="image width, px (default 320)")
    ap.add_argument("--height", type=int, default=240, help="image height, px (default 240)")
    ap.add_argument("--json", default=None, help="write all results to this JSON file (must not exist)")
    args = ap.parse_args()
    out: dict[str, list] = {}
    for kind in args.kinds.split(","):
        rows = []
        for seed in tqdm(range(args.n), desc=f"{kind} ({args.features})", file=sys.stderr):
            rows.append(run_servo(kind, seed, features=args.features, duration=args.duration,
                                  interaction=args.interaction,
                                  intrinsics=CameraIntrinsics.default(args.width, args.height)).summary())
        out[kind] = rows
        ok = [r for r in rows if r["converged"]]
        t = np.array([r["time_to_converge"] for r in ok])
        px = np.array([r["final_corner_error_px"] for r in ok])
        te = np.array([r["final_translation_error_m"] for r in ok]) * 1000
        re = np.array([r["final_rotation_error_deg"] for r in ok])
        label = f"{kind.upper()}" + (f" {args.interaction}" if kind == "ibvs" else "")
        print(f"{label} ({args.features} features, {args.width}x{args.height}): success {len(ok)}/{len(rows)}"
              f" = {100 * len(ok) / len(rows):.1f}%")
        if ok:
            print(f"  time to converge: median {np.median(t):.2f} s, 95th pct {np.percentile(t, 95):.2f} s, "
                  f"max {t.max():.2f} s")
            print(f"  final corner error: max {px.max():.3f} px; pose error max {te.max():.3f} mm, "
                  f"{re.max():.3f} deg")
        failed = [r["seed"] for r in rows if not r["converged"]]
        if failed:
            print(f"  not converged: seeds {failed}")
    if args.json:
        from pathlib import Path

        p = Path(args.json)
        if p.exists():
            raise SystemExit(f"{p} exists; choose another --json path")
        p.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
