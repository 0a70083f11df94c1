"""``franka-vs diagnose LOG [--json] [--model FILE]``: which physical effect does the model lack?

``--json`` prints one JSON object: ``rmse_tau`` (7, Nm), ``rmse_tau_total``, ``noise_floor`` (7), ``ranking`` (best
first: ``effect``, ``joints``, ``params``, ``rmse_tau_after``, ``score``, plus ``significant``, ``plausible``,
``removed_rms``), ``verdict`` (the top effect or ``"none"``) and ``selected`` (effects to add together, stopping at
the noise floor). Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from franka_vs_gym.validation.cli_common import add_common, settings_from
from franka_vs_gym.validation.compare import progress


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument("--effects", default=None, metavar="E1,E2",
                        help="candidate effects (default: the whole library)")


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.io import OutputSet
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.logs import sidecar_path

    verbose = not args.quiet
    effects = None if args.effects is None else [e for e in args.effects.split(",") if e.strip()]
    inputs = [p for p in (args.log, sidecar_path(args.log), args.model) if p]
    with OutputSet(force=args.force, inputs=inputs) as outputs:
        report_tmp = outputs.folder(args.report, what="report folder") if args.report else None
        d = diagnose(args.log, args.model, rigid_body=args.rigid_body, effects=effects, settings=settings_from(args),
                     verbose=verbose)
        if report_tmp is not None:
            from franka_vs_gym.validation.compare import compare
            from franka_vs_gym.validation.report import markdown_report

            progress("writing the report and figures", verbose)
            res = compare(d.context.data, d.config, do_replay=False)
            markdown_report(res, report_tmp, diagnosis=d, overwrite=True)
    if args.report:
        progress(f"report: {args.report}/report.md", verbose)
    if args.json:
        print(json.dumps(d.to_dict()))
        return 0
    print(f"baseline RMSE (Nm): {np.round(d.rmse_tau, 3).tolist()}  total {d.rmse_tau_total:.3f}")
    print(f"noise floor   (Nm): {np.round(d.noise_floor, 3).tolist()}")
    print("rank  effect                               score  sig  plaus  joints                 RMSE after (Nm)")
    for i, c in enumerate(d.ranking):
        print(f"{i + 1:4d}  {c.effect:34s} {c.score:8.1f}  {'yes' if c.significant else 'no ':3s}  "
              f"{'yes' if c.plausible else 'no ':5s}  {str(c.joints):22s} {np.round(c.rmse_tau_after, 3).tolist()}")
    print(f"verdict: {d.verdict}")
    if d.selected:
        print(f"add together (down to the noise floor): {','.join(d.selected)}  ->  "
              f"franka-vs fit {args.log} --add {','.join(d.selected)} -o calibrated.json")
    return 0
