"""``franka-vs fit LOG --add EFFECT[,EFFECT...] -o FILE``: fit effects, apply them to the model and the plant, save
the calibrated model file, and show the error before and after per joint."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from franka_vs_gym.validation.cli_common import add_common, settings_from
from franka_vs_gym.validation.compare import progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser)
    parser.add_argument("--add", required=True, metavar="EFFECT[,EFFECT...]",
                        help="effects to fit (see 'franka-vs diagnose'), or 'auto' for the diagnosis' selection")
    parser.add_argument("-o", "--output", required=True, metavar="FILE", help="calibrated model file to write (JSON)")
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.io import OutputSet
    from franka_vs_gym.validation.diagnose import fit_effects
    from franka_vs_gym.validation.logs import sidecar_path

    out = Path(args.output)
    effects = [e for e in args.add.split(",") if e.strip()]
    if not effects:
        raise ValueError("--add needs at least one effect")
    verbose = not args.quiet
    # the model and the report appear together or not at all; outputs are refused before the fit runs, and no
    # output may be one of the inputs (the log, its sidecar, --model), whatever --force says
    inputs = [p for p in (args.log, sidecar_path(args.log), args.model) if p]
    with OutputSet(force=args.force, inputs=inputs) as outputs:
        model_tmp = outputs.file(out, what="calibrated model file")
        report_tmp = outputs.folder(args.report, what="report folder") if args.report else None
        res = fit_effects(args.log, effects, args.model, rigid_body=args.rigid_body, settings=settings_from(args),
                          verbose=verbose)
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
    warnings = res.after.plausibility_warnings()
    for w in warnings:
        print(f"franka-vs fit: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps({**res.to_dict(), "model_file": str(out), "warnings": warnings}))
        return 0
    print("joint   before   after   noise floor  (torque RMSE, Nm)")
    for j in range(7):
        print(f"{j:5d}  {res.rmse_before[j]:7.3f}  {res.rmse_after[j]:6.3f}  {res.noise_floor[j]:8.3f}")
    tb, ta = float(np.sqrt(np.mean(res.rmse_before ** 2))), float(np.sqrt(np.mean(res.rmse_after ** 2)))
    print(f"total  {tb:7.3f}  {ta:6.3f}")
    print(f"effects: {', '.join(res.effects) or 'none'}; parameters: {json.dumps(res.params)}")
    print(f"calibrated model: {out}")
    return 0
