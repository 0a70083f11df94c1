"""``franka-vs excite --effects E1,E2 | --separate A,B | --from diagnosis.json -o DIR``: design the motion to record
next (an excitation trajectory optimised for the predicted interval widths of the effects in question) and write it
with scripts that play and record it on the robot.

DIR receives ``trajectory.csv`` (time, q_d[i], dq_d[i], ddq_d[i] at 1 kHz), ``play_excitation_pylibfranka.py`` and
``play_excitation_franky.py`` (``python SCRIPT ROBOT_ADDRESS``: the same script runs against ``franka-vs serve`` and
a real robot; the recording goes next to the script) and ``excite.json`` (the design: predicted 95 % interval
widths of the designed motion next to those of the reference, the limits it keeps, the motion's coefficients).
``--report DIR`` writes the design's report (:mod:`franka_vs_gym.validation.report.excite`).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from franka_vs_gym.validation.excite import NEFF_RATE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    q = parser.add_argument_group("the question (one or more)")
    q.add_argument("--effects", default=None, metavar="E1,E2",
                   help="effects whose parameters the motion should identify (e.g. payload,coulomb_friction)")
    q.add_argument("--separate", action="append", default=[], metavar="A,B",
                   help="effects the motion should tell apart (repeatable)")
    q.add_argument("--from", dest="from_", default=None, metavar="DIAGNOSIS.json",
                   help="a 'franka-vs diagnose --json' output: its ambiguous groups are separated, else its selected "
                        "effects identified")
    parser.add_argument("-o", "--output", required=True, metavar="DIR", help="folder to write (must not exist)")
    parser.add_argument("--duration", type=float, default=30.0, help="length of the motion, s (default 30)")
    parser.add_argument("--criterion", choices=("D", "E"), default="D",
                        help="D-optimal (log det of the information, default) or E-optimal (its smallest eigenvalue)")
    parser.add_argument("--log", default=None,
                        help="the log that raised the question: the reference the design is compared with (default: "
                             "the generic excitation of the same duration) and the noise floor used")
    parser.add_argument("--model", default=None, metavar="FILE", help="calibrated model file (default: the FER)")
    parser.add_argument("--robot", default=None, help="robot description (fer, fr3, ...) when no --model is given")
    parser.add_argument("--fraction", type=float, default=0.5,
                        help="fraction of the robot's velocity, acceleration and jerk limits the motion may use "
                             "(default 0.5)")
    parser.add_argument("--position-margin", type=float, default=0.2, metavar="RAD",
                        help="distance kept from the joint position limits, rad (default 0.2)")
    parser.add_argument("--clearance", type=float, default=0.15, metavar="M",
                        help="height of the flange over the table top (base z = 0), m; end effector and wrist keep "
                             "half of it (default 0.15; 0 disables the check)")
    parser.add_argument("--rest", type=float, default=1.0, help="rest at each end of the motion, s (default 1)")
    parser.add_argument("--neff-rate", type=float, default=NEFF_RATE, metavar="HZ",
                        help=f"effective independent samples per second of a 1 kHz log, for the predicted widths "
                             f"(default {NEFF_RATE:g})")
    parser.add_argument("--seed", type=int, default=0, help="seed of the starting points (default 0)")
    parser.add_argument("--time-budget", type=float, default=45.0, metavar="S",
                        help="seconds the optimiser may use (default 45)")
    parser.add_argument("--evaluations", type=int, default=None, metavar="N",
                        help="stop the search after N criterion evaluations (the same design on any machine); the "
                             "time budget still applies")
    parser.add_argument("--report", metavar="DIR", default=None,
                        help="write the design's report into DIR: report.html (one interactive file, opens offline: "
                             "the motion against the limits, the predicted widths against the reference, what it "
                             "tells apart, the commands to run it), report.md and PNG figures")
    parser.add_argument("--json", action="store_true", help="print the design as one JSON object on stdout")
    parser.add_argument("--force", action="store_true", help="replace an existing output folder")
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")


def question_from(path: str) -> tuple[list[str], list[list[str]]]:
    """(effects, groups to separate) read from a diagnosis JSON: ``ambiguous`` (``[[A, B], ...]``, or the
    ``candidates`` of ``ambiguity``) when present and non-empty, else the ``selected`` effects."""
    from franka_vs_gym import io
    from franka_vs_gym.errors import UserError

    try:
        d = json.loads(io.read_text(path, what="diagnosis file"))
    except json.JSONDecodeError as e:
        raise UserError(f"{path}: not a JSON file ({e.msg} at line {e.lineno})") from None
    if not isinstance(d, dict):
        raise UserError(f"{path}: expected the JSON object of 'franka-vs diagnose --json'")
    amb = d.get("ambiguous") or []
    if not amb and isinstance(d.get("ambiguity"), list):  # the detailed form: [{"candidates": [A, B], ...}]
        amb = [a.get("candidates") for a in d["ambiguity"] if isinstance(a, dict)]
    if not isinstance(amb, list) or not all(isinstance(g, list) and all(isinstance(x, str) for x in g) for g in amb):
        raise UserError(f"{path}: 'ambiguous' must be a list of lists of effect names")
    groups = [g for g in amb if len(g) >= 2]
    sel = d.get("selected") or []
    effects = []
    for s in sel:
        name = s.get("effect") if isinstance(s, dict) else s
        if isinstance(name, str) and name not in effects:
            effects.append(name)
    if groups:
        return [], groups
    if not effects:
        raise UserError(f"{path}: the diagnosis names no ambiguous or selected effect: nothing to design for")
    return effects, []


def _config(args: argparse.Namespace):
    from franka_vs_gym.model.config import resolve_config

    return resolve_config(args.model, args.robot)


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.errors import UserError
    from franka_vs_gym.io import OutputSet
    from franka_vs_gym.validation.compare import as_processed, progress
    from franka_vs_gym.validation.excite import design_excitation
    from franka_vs_gym.validation.excite_scripts import scripts, trajectory_csv, trajectory_table

    verbose = not args.quiet
    effects = [e.strip() for e in (args.effects or "").split(",") if e.strip()]
    groups = [[e.strip() for e in g.split(",") if e.strip()] for g in args.separate]
    if args.from_:
        fe, fg = question_from(args.from_)
        effects += [e for e in fe if e not in effects]
        groups += fg
    if not effects and not groups:
        raise UserError("name the question: --effects E1,E2, --separate A,B or --from diagnosis.json")
    for g in groups:
        if len(g) < 2:
            raise UserError(f"--separate needs two or more effects separated by commas, got {','.join(g)!r}")
    for name, v in (("--duration", args.duration), ("--time-budget", args.time_budget),
                    ("--neff-rate", args.neff_rate)):
        if not (v > 0 and np.isfinite(v)):
            raise UserError(f"{name} must be a positive number, got {v}")
    if args.evaluations is not None and args.evaluations < 1:
        raise UserError(f"--evaluations must be >= 1, got {args.evaluations}")
    if not 0 < args.fraction <= 1:
        raise UserError(f"--fraction must be in (0, 1], got {args.fraction}")
    if args.clearance < 0 or args.rest < 0 or args.position_margin < 0:
        raise UserError("--clearance, --rest and --position-margin must be >= 0")
    cfg = _config(args)
    reference = None
    inputs = [Path(p) for p in (args.log, args.model, args.from_) if p]
    with OutputSet(force=args.force, inputs=inputs) as outputs:
        folder = outputs.folder(args.output, what="excitation folder")
        report_dir = outputs.folder(args.report, what="report folder") if args.report else None
        if args.log:
            from franka_vs_gym.validation.loading import load_log

            progress(f"reading the reference log {args.log}", verbose)
            reference = as_processed(load_log(args.log, progress=verbose))
            if args.robot is None and args.model is None:  # the robot the log declares (in words too), as compare
                from franka_vs_gym.model.config import resolve_config
                from franka_vs_gym.validation.compare import declared_robot

                key, declared = declared_robot(reference.log)
                if declared is not None and declared != cfg.robot.name:
                    cfg = resolve_config(None, declared)
                    progress(f"designing for the {declared.upper()}: the log's {key!r} says so (--robot overrides)",
                             verbose)
        try:
            d = design_excitation(effects, separate=groups, duration=args.duration, config=cfg,
                                  criterion=args.criterion, rest=args.rest, fraction=args.fraction,
                                  pos_margin=args.position_margin, clearance=args.clearance,
                                  neff_rate=args.neff_rate, reference=reference, seed=args.seed,
                                  time_budget=args.time_budget, max_evaluations=args.evaluations,
                                  verbose=verbose)
        except ValueError as e:
            raise UserError(str(e)) from None
        out = d.to_dict()
        table = trajectory_table(d.motion)
        (folder / "trajectory.csv").write_text(trajectory_csv(d.motion, table=table))
        for name, text in scripts(d).items():
            (folder / name).write_text(text)
        (folder / "excite.json").write_text(json.dumps(out, indent=1))
        if report_dir is not None:  # from what was just written: the design's dict and trajectory.csv's rows
            from franka_vs_gym.validation.cli_common import alongside
            from franka_vs_gym.validation.report.excite import html_excite, markdown_excite, view

            progress("writing the report: report.html, report.md and figures", verbose)
            v = view(out, table, args.output, d.seconds)
            join = alongside(lambda: markdown_excite(v, report_dir))  # a second process where a CPU is free
            html_excite(v, report_dir)
            join()
    progress(f"written: {args.output}/trajectory.csv, play_excitation_pylibfranka.py, play_excitation_franky.py, "
             "excite.json" + (f"; report {args.report}/report.html" if args.report else ""), verbose)
    if args.json:
        print(json.dumps({**out, "output": str(args.output)}))
        return 0
    print(f"designed for: {', '.join(d.effects)}" + (f"; to separate: {d.separate}" if d.separate else "")
          + f" ({d.criterion}-optimal, {d.motion.duration:g} s, designed in {d.seconds:.1f} s)")
    print(f"noise model: {out['noise_model']}")
    print(f"reference: {d.reference}")
    print("parameter                               95% width designed   reference   ratio")
    for n, a, b in zip(d.names, d.widths, d.widths_reference, strict=True):
        ratio = b / a if np.isfinite(a) and np.isfinite(b) and a > 0 else float("nan")
        print(f"{n:40s} {a:14.4g} {b:12.4g} {ratio:7.2f}")
    for s in d.summary():
        print(f"{s['effect']}: intervals {s['median_width_ratio_reference_over_designed']:.2f}x narrower than the "
              "reference (median over its parameters)")
    for which, pairs in d.collinearity.items():
        print(f"collinearity ({which}, cos of the smallest principal angle, 1 = indistinguishable): "
              + ", ".join(f"{k} {v:.2f}" for k, v in pairs.items()))
    lim = d.limits
    print(f"limits: peak dq {max(lim['peak_dq_over_limit']):.2f}, ddq {max(lim['peak_ddq_over_limit']):.2f}, dddq "
          f"{max(lim['peak_dddq_over_limit']):.3f} of the robot's; lowest flange {lim['lowest_flange_m']} m "
          "over the table")
    print(f"record it: python {args.output}/play_excitation_pylibfranka.py ROBOT_ADDRESS "
          "(or play_excitation_franky.py)")
    if args.report:
        print(f"report: {Path(args.report) / 'report.html'} (open in a browser)")
    sys.stdout.flush()
    return 0
