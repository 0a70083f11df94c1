"""``franka-vs fit LOG --add EFFECT[,EFFECT...] -o FILE``: fit effects, apply them to the model and the plant, save
the calibrated model file, and show the error before and after per joint."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from franka_vs_gym.validation.cli_common import (
    add_common,
    carried_flags,
    input_paths,
    load_from,
    one_blas_thread,
    say_outputs,
    settings_from,
    stage_views,
    write_views,
)
from franka_vs_gym.validation.compare import progress_line


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
    from franka_vs_gym.validation.fitting import fit_effects

    out = Path(args.output)
    effects = [e for e in args.add.split(",") if e.strip()]
    if not effects:
        raise ValueError("--add needs at least one effect")
    verbose = not args.quiet
    if not 0 <= args.holdout < 0.9:
        raise ValueError(f"--holdout must be in [0, 0.9), got {args.holdout}")
    # the model, the report and the MCAP log appear together or not at all; outputs are refused before the fit
    # runs, and no output may be one of the inputs (the log, its sidecar, --model), whatever --force says
    with OutputSet(force=args.force, inputs=input_paths(args)) as outputs:
        model_tmp = outputs.file(out, what="calibrated model file")
        report_tmp, mcap_tmp = stage_views(args, outputs)
        with progress_line(args.verbose), one_blas_thread():
            res = fit_effects(load_from(args), effects, args.model, rigid_body=args.rigid_body,
                              settings=settings_from(args), verbose=verbose, holdout=args.holdout or None,
                              tool=args.tool, robot=args.robot)
            res.after.save(model_tmp, overwrite=True)
            model_warnings = res.after.plausibility_warnings()  # values outside the FER's specification
            if report_tmp is not None or mcap_tmp is not None:
                from franka_vs_gym.validation.compare import compare

                # what remains with the calibrated model
                cmp_after = compare(res.data, res.after, robot=res.after.robot, do_replay=False)
                write_views(cmp_after, report_tmp, mcap_tmp, fit=res, model_file=str(out), verbose=verbose,
                            summary={**res.to_dict(), "model_file": str(out), "model_warnings": model_warnings})
    for w in model_warnings:
        print(f"franka-vs fit: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps({**res.to_dict(), "model_file": str(out), "model_warnings": model_warnings}))
        return 0
    from franka_vs_gym.validation.report.content import correlation_lines, fit_lines, next_command

    # the fitted values first (one line per effect), then the error before and after
    tb, ta = float(np.sqrt(np.mean(res.rmse_before ** 2))), float(np.sqrt(np.mean(res.rmse_after ** 2)))
    print(f"fitted: {', '.join(res.effects) or 'nothing'}; total torque RMSE {tb:.3f} -> {ta:.3f} Nm")
    for line in fit_lines(res):
        print(line)
    if res.holdout is not None:
        h = res.holdout
        print(f"held-out check ({h['split']}): total RMSE {h['rmse_tau_total_before']:.3f} -> "
              f"{h['rmse_tau_total_after']:.3f} Nm" + (f"; dropped {h['dropped']}" if h["dropped"] else ""))
    for name, why in res.notes.items():
        print(f"{name}: {why}")
    for line in correlation_lines(res.correlations, res.unidentifiable, verbose=args.verbose):
        print(line)
    a = res.assumptions
    for w in a["warnings"]:
        print(f"warning: {w}")
    print("joint            " + " ".join(f"{j:>6d}" for j in range(7)))
    print("before (Nm)      " + " ".join(f"{x:6.3f}" for x in res.rmse_before))
    print("after (Nm)       " + " ".join(f"{x:6.3f}" for x in res.rmse_after))
    print("noise floor (Nm) " + " ".join(f"{x:6.3f}" for x in res.noise_floor))
    if args.verbose:
        print(f"assumptions: tool {a['tool']} ({a['tool_source']}), gravity {a['gravity_m_per_s2']} m/s^2, log "
              f"rate {a['log_rate_hz']} Hz, processed at {a['resampled_to_hz']:g} Hz")
        if a.get("log_read_as"):
            print(f"log read as: {a['log_read_as']}")
        print(f"parameters: {json.dumps(res.params)}")
    print(f"calibrated model: {out}")
    for line in say_outputs(args):
        print(line)
    print(f"next: {next_command(args.log, fit=res, model_file=str(out), flags=carried_flags(args, True))}")
    return 0
