"""``franka-vs fit LOG --add EFFECT[,EFFECT...] -o FILE``: fit effects, apply them to the model and the plant, save
the calibrated model file, and show the error before and after per joint."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from franka_vs_gym.validation.cli_common import add_common, input_paths, load_from, settings_from
from franka_vs_gym.validation.compare import progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser)
    parser.add_argument("--add", required=True, metavar="EFFECT[,EFFECT...]",
                        help="effects to fit (see 'franka-vs diagnose'), or 'auto' for the diagnosis' selection")
    parser.add_argument("-o", "--output", required=True, metavar="FILE", help="calibrated model file to write (JSON)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument("--holdout", type=float, default=0.25, metavar="FRACTION",
                        help="held-out validation: fit on the first 1-FRACTION of the log, keep only effects that "
                             "lower "
                             "the RMSE on the last FRACTION (default 0.25; 0 disables)")


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.io import OutputSet
    from franka_vs_gym.validation.diagnose import fit_effects

    out = Path(args.output)
    effects = [e for e in args.add.split(",") if e.strip()]
    if not effects:
        raise ValueError("--add needs at least one effect")
    verbose = not args.quiet
    if not 0 <= args.holdout < 0.9:
        raise ValueError(f"--holdout must be in [0, 0.9), got {args.holdout}")
    # the model and the report appear together or not at all; outputs are refused before the fit runs, and no
    # output may be one of the inputs (the log, its sidecar, --model), whatever --force says
    with OutputSet(force=args.force, inputs=input_paths(args)) as outputs:
        model_tmp = outputs.file(out, what="calibrated model file")
        report_tmp = outputs.folder(args.report, what="report folder") if args.report else None
        res = fit_effects(load_from(args), effects, args.model, rigid_body=args.rigid_body,
                          settings=settings_from(args), verbose=verbose, holdout=args.holdout or None,
                          tool=args.tool, robot=args.robot)
        res.after.save(model_tmp, overwrite=True)
        if report_tmp is not None:
            from franka_vs_gym.validation.compare import compare
            from franka_vs_gym.validation.report import markdown_report

            progress("writing the report and figures", verbose)
            cmp_after = compare(res.data, res.after, do_replay=False)
            markdown_report(cmp_after, report_tmp, fit=res, overwrite=True)
    progress(f"calibrated model written to {out}", verbose)
    if args.report:
        progress(f"report: {Path(args.report) / 'report.md'}", verbose)
    model_warnings = res.after.plausibility_warnings()  # values a user may mean but outside the FER's specification
    for w in model_warnings:
        print(f"franka-vs fit: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps({**res.to_dict(), "model_file": str(out), "model_warnings": model_warnings}))
        return 0
    a = res.assumptions
    print(f"assumptions: tool {a['tool']} ({a['tool_source']}), gravity {a['gravity_m_per_s2']} m/s^2, log rate "
          f"{a['log_rate_hz']} Hz, processed at {a['resampled_to_hz']:g} Hz")
    if a.get("log_read_as"):
        print(f"log read as: {a['log_read_as']}")
    for w in a["warnings"]:
        print(f"warning: {w}")
    if res.holdout is not None:
        h = res.holdout
        print(f"held-out check ({h['split']}): total RMSE {h['rmse_tau_total_before']:.3f} -> "
              f"{h['rmse_tau_total_after']:.3f} Nm" + (f"; dropped {h['dropped']}" if h["dropped"] else ""))
    print("joint   before   after   noise floor  (torque RMSE on the whole log, Nm)")
    for j in range(7):
        print(f"{j:5d}  {res.rmse_before[j]:7.3f}  {res.rmse_after[j]:6.3f}  {res.noise_floor[j]:8.3f}")
    tb, ta = float(np.sqrt(np.mean(res.rmse_before ** 2))), float(np.sqrt(np.mean(res.rmse_after ** 2)))
    print(f"total  {tb:7.3f}  {ta:6.3f}")
    for name, why in res.notes.items():
        print(f"{name}: {why}")
    print(f"effects: {', '.join(res.effects) or 'none'}; parameters: {json.dumps(res.params)}")
    if res.params_ci95:
        from franka_vs_gym.validation.uncertainty import format_params

        for name in res.effects:
            if name in res.params_ci95:
                shown = {k: v for k, v in res.params[name].items() if k not in ("joints", "problems")}
                print(f"  {name} with 95% intervals: "
                      f"{format_params(shown, res.params_ci95[name], res.params[name].get('joints'))}")
        corr = sorted(res.correlations, key=lambda c: -abs(c["r"]))
        for c in corr[:5]:
            print(f"  correlated: {c['a']} and {c['b']} (r = {c['r']})")
        if len(corr) > 5:
            print(f"  correlated: {len(corr) - 5} more pairs with abs(r) > 0.9 (see --json)")
        for u in res.unidentifiable:
            print(f"  not identifiable: {u}")
    print(f"calibrated model: {out}")
    return 0
