#!/usr/bin/env python
"""Score ``franka-vs diagnose`` on logs from the independent generator (tests/independent_logs.py): clean logs,
single and compound (2 and 3) library-type effects, effects outside the library, at randomised magnitudes and
seeds, at 1 kHz and at lower rates. Prints a Markdown table of rates (the one in docs/workbench.md) and writes the
per-log results as JSON.

    python scripts/workbench_study.py --seeds 10 -o study.json       # about 5 min on one core
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from independent_logs import LIBRARY_TYPE, OUTSIDE, make_log, score  # noqa: E402

from franka_vs_gym.io import atomic_write  # noqa: E402
from franka_vs_gym.validation.diagnose import diagnose  # noqa: E402

COMPOUND2 = [("payload", "viscous"), ("offset", "delay"), ("tilt", "coulomb"), ("armature", "stribeck"),
             ("payload", "coulomb")]
COMPOUND3 = [("coulomb", "tilt", "armature"), ("viscous", "payload", "offset"), ("delay", "coulomb", "tilt")]


def cases(seeds: int):
    for s in range(seeds):
        yield "none", (), s
        for e in LIBRARY_TYPE:
            yield "single", (e,), s
        yield "compound2", COMPOUND2[s % len(COMPOUND2)], s
        yield "compound2", COMPOUND2[(s + 2) % len(COMPOUND2)], s + 100
        yield "compound3", COMPOUND3[s % len(COMPOUND3)], s
        yield "compound3", COMPOUND3[(s + 1) % len(COMPOUND3)], s + 100
        for e in OUTSIDE:
            yield "outside", (e,), s
        yield "outside+library", (OUTSIDE[s % len(OUTSIDE)], LIBRARY_TYPE[s % len(LIBRARY_TYPE)]), s + 200


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--rates", default="1000,100,30", help="log rates to test, Hz (comma-separated)")
    p.add_argument("-o", "--output", default=None, help="per-log results (JSON)")
    p.add_argument("--force", action="store_true")
    args = p.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    rows = []
    all_cases = list(cases(args.seeds))
    t_start = time.perf_counter()
    for rate in rates:
        for i, (cat, effects, seed) in enumerate(all_cases):
            log, truth = make_log(list(effects), seed, duration=args.duration, rate=rate)
            t0 = time.perf_counter()
            try:
                d = diagnose(log)
            except ValueError as exc:  # e.g. refused: too little data
                rows.append({"rate": rate, "category": cat, "effects": list(effects), "seed": seed, "ok": False,
                             "error": str(exc)})
                continue
            s = score(list(effects), d)
            rows.append({**s, "rate": rate, "category": cat, "effects": list(effects), "seed": seed,
                         "diagnose_s": round(time.perf_counter() - t0, 3), "explained": d.explained})
            print(f"[{rate:5.0f} Hz {i + 1:3d}/{len(all_cases)}] {cat:16s} {'+'.join(effects) or 'none':26s} "
                  f"{'ok ' if s['ok'] else 'BAD'} selected={s['selected']} explained={d.explained}",
                  file=sys.stderr, flush=True)
    print(f"# {len(rows)} logs in {time.perf_counter() - t_start:.0f} s", file=sys.stderr)
    cats = ["none", "single", "compound2", "compound3", "outside", "outside+library"]
    print("| category | what counts as right | " + " | ".join(f"{r:.0f} Hz" for r in rates) + " |")
    print("|---|---|" + "---|" * len(rates))
    what = {"none": "verdict `none`, explained", "single": "the effect named, nothing else",
            "compound2": "both named, nothing else", "compound3": "all three named, nothing else",
            "outside": "`explained: false`", "outside+library": "library effect named and `explained: false`"}
    for c in cats:
        cells = []
        for r in rates:
            sub = [x for x in rows if x["category"] == c and x["rate"] == r]
            cells.append(f"{sum(x['ok'] for x in sub)}/{len(sub)}")
        print(f"| {c} | {what[c]} | " + " | ".join(cells) + " |")
    for r in rates:
        sub = [x for x in rows if x["category"] == "single" and x["rate"] == r]
        bad = sorted({"+".join(x["effects"]) for x in sub if not x["ok"]})
        print(f"\n{r:.0f} Hz single-effect misses: {bad or 'none'}")
        sub = [x for x in rows if x["category"] == "outside" and x["rate"] == r]
        bad = sorted({"+".join(x["effects"]) for x in sub if not x["ok"]})
        print(f"{r:.0f} Hz outside-library misses: {bad or 'none'}")
        ts = [x["diagnose_s"] for x in rows if x["rate"] == r and "diagnose_s" in x]
        if ts:
            print(f"{r:.0f} Hz diagnose time per {args.duration:g} s log: median {np.median(ts):.2f} s, "
                  f"max {max(ts):.2f} s")
    if args.output:
        atomic_write(args.output, json.dumps(rows, indent=1), force=args.force)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
