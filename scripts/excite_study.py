#!/usr/bin/env python
"""The excitation study of docs/workbench/evidence.md ("The excitation study"): for each question, design a motion with
``franka-vs excite``'s optimiser and print the predicted 95 % interval widths against the generic excitation of the
same duration (median ratio over each effect's parameters, collinearity of the pairs to separate, time).

    python scripts/excite_study.py                      # 9 questions x the 45 s budget: about 7 min
    python scripts/excite_study.py --duration 30 --budget 20 --only payload,armature
"""

from __future__ import annotations

import argparse
import json
import time

from franka_vs_gym.validation.excite import design_excitation

QUESTIONS = [(["payload"], []), (["armature"], []), (["delay"], []), (["viscous_friction"], []),
             (["gravity_tilt"], []), (["coulomb_friction"], []), ([], [["coulomb_friction", "torque_offset"]]),
             ([], [["armature", "delay"]]), ([], [["viscous_friction", "delay"]])]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--budget", type=float, default=45.0, help="search budget per question, s (wall)")
    ap.add_argument("--only", default=None, help="comma-separated effects: only the questions naming them")
    ap.add_argument("--json", action="store_true", help="one JSON line per question instead of the table")
    a = ap.parse_args()
    only = set(a.only.split(",")) if a.only else None
    if not a.json:
        print("| question | designed / generic: 95 % width ratio (median) | collinearity generic -> designed | "
              "time (s) |")
        print("|---|---|---|---|")
    for eff, sep in QUESTIONS:
        names = set(eff) | {x for g in sep for x in g}
        if only and not names & only:
            continue
        t0, c0 = time.perf_counter(), time.process_time()
        d = design_excitation(eff, separate=sep, duration=a.duration, time_budget=a.budget)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        ratios = {s["effect"]: s["median_width_ratio_reference_over_designed"] for s in d.summary()}
        col = {k: (d.collinearity["reference"][k], v) for k, v in d.collinearity.get("designed", {}).items()}
        if a.json:
            print(json.dumps({"effects": eff, "separate": sep, "ratios": ratios, "collinearity": col,
                              "wall_s": wall, "cpu_s": cpu, "evaluations": d.evaluations}), flush=True)
            continue
        q = f"--effects {','.join(eff)}" if eff else " ".join(f"--separate {','.join(g)}" for g in sep)
        r = " / ".join(f"{v:.2f}" for v in ratios.values())
        c = ", ".join(f"{g:.2f} -> {v:.2f}" for g, v in col.values()) if sep else ""
        print(f"| `{q}` | {r} | {c} | {wall:.0f} wall, {cpu:.1f} CPU |", flush=True)


if __name__ == "__main__":
    main()
