#!/usr/bin/env python
"""Score ``franka-vs diagnose`` on logs from the two independent generators (tests/independent_logs.py, "A": inverse
dynamics of three-sine trajectories, white noise; tests/independent_logs_b.py, "B": point-to-point, multi-sine and
near-static trajectories, coloured noise, quantisation, dropped rows, ROS-like low-rate sampling, effects outside
the library such as joint elasticity, presliding friction, cable springs, gear ripple): clean logs, single and
compound (2 and 3) library-type effects, effects outside the library, at randomised magnitudes and seeds, at 1 kHz
and at lower rates. Prints Markdown tables of rates (the ones in docs/workbench/evidence.md) and writes the per-log
results as JSON. Progress goes to stderr.

    python scripts/workbench_study.py --seeds 6 -o study.json        # both generators, about 6 min on one core
    python scripts/workbench_study.py --generators B --seeds 2
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import independent_logs as gen_a  # noqa: E402
import independent_logs_b as gen_b  # noqa: E402

from franka_vs_gym.io import atomic_write  # noqa: E402
from franka_vs_gym.validation.diagnose import diagnose  # noqa: E402

COMPOUND2_A = [("payload", "viscous"), ("offset", "delay"), ("tilt", "coulomb"), ("armature", "stribeck"),
               ("payload", "coulomb")]
COMPOUND3_A = [("coulomb", "tilt", "armature"), ("viscous", "payload", "offset"), ("delay", "coulomb", "tilt")]
COMPOUND2_B = [("payload", "coulomb"), ("asym", "armature"), ("tilt", "viscous"), ("offset", "loadfric"),
               ("delay", "payload"), ("viscous", "armature")]
COMPOUND3_B = [("payload", "viscous", "offset"), ("tilt", "coulomb", "armature"), ("asym", "payload", "delay"),
               ("loadfric", "tilt", "offset")]
CATS = ["none", "single", "compound2", "compound3", "outside", "outside+library"]
WHAT = {"none": "verdict `none`, explained", "single": "the effect named, nothing else",
        "compound2": "both named, nothing else", "compound3": "all three named, nothing else",
        "outside": "`explained: false`", "outside+library": "library effect named and `explained: false`"}


def cases_a(seeds: int):
    lib, out = gen_a.LIBRARY_TYPE, gen_a.OUTSIDE
    for s in range(seeds):
        yield "none", (), s
        for e in lib:
            yield "single", (e,), s
        yield "compound2", COMPOUND2_A[s % len(COMPOUND2_A)], s
        yield "compound2", COMPOUND2_A[(s + 2) % len(COMPOUND2_A)], s + 100
        yield "compound3", COMPOUND3_A[s % len(COMPOUND3_A)], s
        yield "compound3", COMPOUND3_A[(s + 1) % len(COMPOUND3_A)], s + 100
        for e in out:
            yield "outside", (e,), s
        yield "outside+library", (out[s % len(out)], lib[s % len(lib)]), s + 200


def cases_b(seeds: int):
    lib, out = gen_b.LIBRARY_TYPE, gen_b.OUTSIDE
    for s in range(seeds):
        yield "none", (), s
        yield "none", (), s + 300
        for e in lib:
            yield "single", (e,), s
        yield "compound2", COMPOUND2_B[s % len(COMPOUND2_B)], s
        yield "compound2", COMPOUND2_B[(s + 3) % len(COMPOUND2_B)], s + 100
        yield "compound3", COMPOUND3_B[s % len(COMPOUND3_B)], s
        yield "compound3", COMPOUND3_B[(s + 2) % len(COMPOUND3_B)], s + 100
        for e in out:
            yield "outside", (e,), s
        yield "outside+library", (out[s % len(out)], lib[s % len(lib)]), s + 200
        yield "outside+library", (out[(s + 3) % len(out)], lib[(s + 4) % len(lib)]), s + 400


def run(name: str, seeds: int, duration: float, rates: list[float]) -> list[dict]:
    """Diagnose every case of one generator at every rate; one progress line per log on stderr."""
    rows = []
    all_cases = list(cases_a(seeds) if name == "A" else cases_b(seeds))
    for i, (cat, effects, seed) in enumerate(all_cases):
        if name == "A":
            logs = {r: gen_a.make_log(list(effects), seed, duration=duration, rate=r) for r in rates}
        else:
            lb, truth_b = gen_b.make_logs(list(effects), seed, duration=duration, rates=tuple(rates))
            logs = {r: (lb[r], truth_b) for r in rates}
        for rate in rates:
            log, truth = logs[rate]
            t0 = time.process_time()
            try:
                d = diagnose(log)
            except ValueError as exc:  # e.g. refused: too little data
                rows.append({"generator": name, "rate": rate, "category": cat, "effects": list(effects),
                             "seed": seed, "ok": False, "error": str(exc)})
                continue
            cpu = time.process_time() - t0
            s = gen_a.score(list(effects), d) if name == "A" else gen_b.score(list(effects), d, truth, rate)
            rows.append({**s, "generator": name, "rate": rate, "category": cat, "effects": list(effects),
                         "seed": seed, "diagnose_cpu_s": round(cpu, 3), "explained": bool(d.explained),
                         **({"style": truth["style"]} if name == "B" else {})})
            print(f"[{name} {i + 1:3d}/{len(all_cases)} {rate:5.0f} Hz] {cat:16s} "
                  f"{'+'.join(effects) or 'none':24s} {'ok ' if s['ok'] else 'BAD'} selected={s['selected']} "
                  f"explained={d.explained}", file=sys.stderr, flush=True)
    return rows


def table(rows: list[dict], rates: list[float], name: str) -> str:
    lines = [f"Generator {name}:", "", "| category | what counts as right | "
             + " | ".join(f"{r:.0f} Hz" for r in rates) + " |", "|---|---|" + "---|" * len(rates)]
    for c in CATS:
        cells = []
        for r in rates:
            sub = [x for x in rows if x["category"] == c and x["rate"] == r]
            cells.append(f"{sum(x['ok'] for x in sub)}/{len(sub)}")
        lines.append(f"| {c} | {WHAT[c]} | " + " | ".join(cells) + " |")
    for r in rates:
        sub = [x for x in rows if x["rate"] == r]
        lines.append("")
        for c in CATS:
            bad = sorted({"+".join(x["effects"]) or "none" for x in sub if x["category"] == c and not x["ok"]})
            if bad:
                lines.append(f"{r:.0f} Hz {c} misses: {bad}")
        cw = sum(bool(x.get("confident_wrong")) for x in sub)
        lines.append(f"{r:.0f} Hz confident wrong names (explained with a name fitting no hidden effect): {cw}")
        ts = [x["diagnose_cpu_s"] for x in sub if "diagnose_cpu_s" in x]
        if ts:
            lines.append(f"{r:.0f} Hz diagnose CPU per log: median {np.median(ts):.2f} s, max {max(ts):.2f} s")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=6)
    p.add_argument("--duration", type=float, default=10.0)
    p.add_argument("--rates", default="1000,100,30", help="log rates to test, Hz (comma-separated)")
    p.add_argument("--generators", default="A,B", help="which independent generators (A, B or A,B)")
    p.add_argument("-o", "--output", default=None, help="per-log results (JSON)")
    p.add_argument("--force", action="store_true")
    args = p.parse_args(argv)
    rates = [float(r) for r in args.rates.split(",")]
    gens = [g.strip().upper() for g in args.generators.split(",")]
    if not set(gens) <= {"A", "B"}:
        p.error(f"--generators: expected A and/or B, got {args.generators!r}")
    t_start = time.perf_counter()
    rows = []
    for g in gens:
        rows += run(g, args.seeds, args.duration, rates)
    print(f"# {len(rows)} logs in {time.perf_counter() - t_start:.0f} s", file=sys.stderr)
    for g in gens:
        print(table([x for x in rows if x["generator"] == g], rates, g) + "\n")
    if args.output:
        atomic_write(args.output, json.dumps(rows, indent=1), force=args.force)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
