"""``franka-vs diagnose LOG [--json] [--model FILE] [--effects E1,E2|my_effects.py]``: which physical effects does
the model lack, and is anything left that the library cannot name?

``--json`` prints one JSON object: ``rmse_tau`` (7, Nm), ``rmse_tau_total``, ``noise_floor`` (7), ``ranking`` (each
effect alone, best first: ``effect``, ``joints``, ``params``, ``rmse_tau_after``, ``score``, ``significant``,
``plausible``, ``removed_rms``, ``problems``), ``verdict`` (the strongest selected effect or ``"none"``),
``selected`` (the set fitted together: ``effect``, ``joints``, ``params``, ``params_ci95`` (the same keys, each
number replaced by its 95 % interval ``[low, high]``, ``null`` where the log cannot identify it), ``correlations``
(parameter pairs with abs(r) > 0.9), ``unidentifiable`` (combinations the log cannot separate, in words),
``contribution`` (Nm removed per joint in context), ``score``), ``rmse_tau_selected``, ``explained`` and
``unexplained`` (what the residual still follows), ``ambiguous`` (lists of effect names the log cannot tell apart)
and ``ambiguity`` (each with ``candidates``, ``joints``, ``evidence`` and ``separate_by``, the motion that would
separate them), ``changes`` (the model changes during the log: ``t``, ``what``, ``before``, ``after``),
``assumptions`` (tool, gravity, rate, cleaning, warnings) and ``notes`` (why effects were rejected). Progress goes to
stderr.
"""

from __future__ import annotations

import argparse
import json
import sys

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
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument("--effects", default=None, metavar="E1,E2|FILE.py",
                        help="candidate effects (default: the whole library); a .py file is a plug-in whose Effect "
                             "classes are ranked with the library's")
    parser.add_argument("--band-evidence", action="store_true",
                        help="score every effect in the motion band by the information criterion alone (= --evidence "
                             "band_only; docs/workbench/method.md, step 2)")
    parser.add_argument("--evidence", choices=("band", "band_only", "full"), default=None,
                        help="how effects are scored: band (default: the motion band below the cleaning cutoff; "
                             "shared effects judged with the noise the set with them leaves, the 43-parameter link "
                             "inertials also by the held-out blocks, a gravity tilt by its horizontal part), "
                             "band_only (= --band-evidence: the motion band, the information criterion alone) or "
                             "full (every sample of the residual counts, the default before); "
                             "docs/workbench/method.md, step 2")


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.io import OutputSet
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.report.content import correlation_lines, next_command, verdict_lines

    verbose = not args.quiet
    effects = None if args.effects is None else [e for e in args.effects.split(",") if e.strip()]
    with OutputSet(force=args.force, inputs=input_paths(args)) as outputs:
        report_tmp, mcap_tmp = stage_views(args, outputs)
        with progress_line(args.verbose), one_blas_thread():
            d = diagnose(load_from(args), args.model, rigid_body=args.rigid_body, effects=effects,
                         settings=settings_from(args), verbose=verbose, tool=args.tool, robot=args.robot,
                         band_evidence=args.band_evidence, evidence=args.evidence)
            model_warnings = d.config.plausibility_warnings()
            if report_tmp is not None or mcap_tmp is not None:
                from franka_vs_gym.validation.compare import compare

                res = compare(d.data, d.config, robot=d.config.robot, do_replay=False)
                write_views(res, report_tmp, mcap_tmp, diagnosis=d, model_file=args.model,
                            summary={**d.to_dict(), "model_warnings": model_warnings}, verbose=verbose)
    # values a user may mean but outside the FER's specification (e.g. a 5 kg tool): said, not refused
    for w in model_warnings:
        print(f"franka-vs diagnose: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps({**d.to_dict(), "model_warnings": model_warnings}))
        return 0
    # the verdict with its fitted values first; details with --verbose
    for line in verdict_lines(d):
        print(line)
    pairs = [c for s in d.selection for c in (getattr(s, "correlations", None) or [])]
    for line in correlation_lines(pairs, verbose=args.verbose):
        print(line)
    after = (f" -> {np.round(d.rmse_tau_selected, 3).tolist()} with the selected set (held out)"
             if d.rmse_tau_selected is not None and d.selection else "")
    print(f"torque RMSE (Nm): {np.round(d.rmse_tau, 3).tolist()}{after}")
    print(f"noise floor (Nm): {np.round(d.noise_floor, 3).tolist()}")
    a = d.assumptions
    for w in a["warnings"]:
        print(f"warning: {w}")
    if args.verbose:
        print(f"assumptions: tool {a['tool']} ({a['tool_source']}), gravity {a['gravity_m_per_s2']} m/s^2, log rate "
              f"{a['log_rate_hz']} Hz, processed at {a['resampled_to_hz']:g} Hz, low-pass "
              f"{a['cleaning']['lowpass_hz']:g} Hz, {a['cleaning']['stale_rows_dropped']} stale rows dropped")
        if a.get("log_read_as"):
            print(f"log read as: {a['log_read_as']}")
        print("each effect alone:")
        print("rank  effect                               score  sig  plaus  joints                 RMSE after (Nm)")
        for i, c in enumerate(d.ranking):
            print(f"{i + 1:4d}  {c.effect:34s} {c.score:8.1f}  {'yes' if c.significant else 'no ':3s}  "
                  f"{'yes' if c.plausible else 'no ':5s}  {str(c.joints):22s} "
                  f"{np.round(c.rmse_tau_after, 3).tolist()}")
        for s in d.selection:
            print(f"selected: {s.effect:26s} joints {s.joints}  removes (Nm) {np.round(s.contribution, 3).tolist()}")
        for n in d.notes:
            print(f"note: {n}")
    else:
        print(f"tool {a['tool']} ({a['tool_source']}); {len(d.ranking)} effects ranked, {len(d.notes)} notes "
              "(--verbose shows the ranking, the notes and the assumptions)")
    for line in say_outputs(args):
        print(line)
    print(f"next: {next_command(args.log, d, flags=carried_flags(args))}")
    return 0
