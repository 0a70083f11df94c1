#!/usr/bin/env python
"""Convergence study of the eye-to-hand baselines: IBVS and PBVS (ViSP's eye-to-hand laws) on
FrankaIBVSEyeToHand-v0 / FrankaPBVSEyeToHand-v0, N seeded episodes each (episode i reset with seed ``--seed + i``).

    python scripts/eval_eye_to_hand.py [--n 100] [--features ideal|detection] [--robot fer|fr3]
                                       [--form EYETOHAND_L_cVe_eJe|EYETOHAND_L_cVf_fVe_eJe|EYETOHAND_L_cVf_fJe]
                                       [--kinds ibvs,pbvs] [--json OUT]

Success is the environment's (IBVS: ||s - s*|| < 0.01, about 0.7 px per corner coordinate at 320x240; PBVS:
5 mm and 0.02 rad), within its 5 s time limit; time to converge is the simulated time of the first success.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import franka_vs_gym
from franka_vs_gym.policies import IBVSEyeToHandPolicy, PBVSEyeToHandPolicy

IDS = {"ibvs": "FrankaIBVSEyeToHand-v0", "pbvs": "FrankaPBVSEyeToHand-v0"}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100, help="episodes per law (default 100)")
    ap.add_argument("--seed", type=int, default=0, help="first episode's seed (default 0)")
    ap.add_argument("--features", default="ideal", choices=["ideal", "detection"])
    ap.add_argument("--robot", default="fer", choices=["fer", "fr3"])
    ap.add_argument("--form", default="EYETOHAND_L_cVe_eJe",
                    choices=["EYETOHAND_L_cVe_eJe", "EYETOHAND_L_cVf_fVe_eJe", "EYETOHAND_L_cVf_fJe"])
    ap.add_argument("--kinds", default="ibvs,pbvs")
    ap.add_argument("--json", default=None, help="write all episodes to this JSON file (must not exist)")
    args = ap.parse_args()
    if args.n < 1:
        ap.error("--n must be >= 1")
    if args.json and Path(args.json).exists():
        ap.error(f"{args.json} exists; choose another --json path")
    out = {}
    for kind in args.kinds.split(","):
        if kind not in IDS:
            ap.error(f"unknown kind {kind!r} (have {list(IDS)})")
        policy = (IBVSEyeToHandPolicy if kind == "ibvs" else PBVSEyeToHandPolicy)(form=args.form, robot=args.robot)
        r = franka_vs_gym.evaluate(policy, IDS[kind], args.n, args.seed,
                                   env_kwargs={"robot": args.robot, "feature_source": args.features})
        eps = r["episodes"]
        t = np.array([e["time_to_converge"] for e in eps if e["success"]])
        print(f"{IDS[kind]} {kind.upper()} ({args.form}, {args.features} features, {args.robot}): success "
              f"{r['success_rate']:.0%} of {args.n}", flush=True)
        if len(t):
            print(f"  time to converge: mean {t.mean():.2f} s, median {np.median(t):.2f} s, 95th pct "
                  f"{np.percentile(t, 95):.2f} s, max {t.max():.2f} s")
        if r["failures"]:
            print(f"  failures: {r['failures']}")
        out[kind] = {k: v for k, v in r.items()}
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
