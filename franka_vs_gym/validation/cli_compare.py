"""``franka-vs compare LOG [--model FILE]``: inverse-dynamics residual, replay and noise floor per joint."""

from __future__ import annotations

import argparse
import json
import sys

from franka_vs_gym.validation.cli_common import (
    add_common,
    input_paths,
    load_from,
    say_outputs,
    settings_from,
    stage_views,
    write_views,
)
from franka_vs_gym.validation.compare import compare, format_compare, progress_line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser)
    parser.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    parser.add_argument("--no-replay", action="store_true", help="skip the simulation replay")
    parser.add_argument("--replay-mode", choices=("controller", "torque", "tracking"), default=None,
                        help="replay the logged controller, the logged commanded torques, or eq. (2) tracking the "
                             "measured motion (default: the first available in that order)")


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.io import OutputSet

    verbose = not args.quiet
    # the report folder and the MCAP file are refused (exist without --force, are inputs...) before the comparison
    # runs, and appear complete or not at all
    with OutputSet(force=args.force, inputs=input_paths(args)) as outputs:
        report_tmp, mcap_tmp = stage_views(args, outputs)
        with progress_line(args.verbose):
            res = compare(load_from(args), args.model, tool=args.tool, robot=args.robot, rigid_body=args.rigid_body,
                          settings=settings_from(args),
                          do_replay=not args.no_replay, replay_mode=args.replay_mode, verbose=verbose)
            write_views(res, report_tmp, mcap_tmp, model_file=args.model, verbose=verbose)
    # values a user may mean but outside the FER's specification (e.g. a 5 kg tool): said, not refused
    model_warnings = res.config.plausibility_warnings()
    for w in model_warnings:
        print(f"franka-vs compare: warning: {w}", file=sys.stderr)
    if args.json:
        print(json.dumps({**res.to_dict(), "model_warnings": model_warnings}))
    else:
        print(format_compare(res))
        for line in say_outputs(args):
            print(line)
    return 0
