"""``franka-vs workbench [LOG]``: the workbench's loop in the browser (a local Bokeh server app; see
docs/workbench_app.md): the residual per joint, the diagnosis, effects toggled on and off with the held-out error,
the arm at the cursor, saving the calibrated model and the report, validating on a second log."""

from __future__ import annotations

import argparse
from pathlib import Path

from franka_vs_gym.validation.cli_common import add_log_options
from franka_vs_gym.validation.signals import CleanSettings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", nargs="?", default=None,
                        help="the log to open (any format 'franka-vs compare' reads); without it, choose one in the "
                             "page")
    parser.add_argument("--port", type=int, default=5006, help="port to serve on (default 5006)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to listen on (default 127.0.0.1: this machine only; another address exposes "
                             "the page, which reads and writes files here, to the network: only on purpose)")
    parser.add_argument("--no-browser", action="store_true",
                        help="do not open a browser (e.g. over SSH: ssh -L 5006:127.0.0.1:5006 HOST, then open "
                             "http://127.0.0.1:5006/ locally)")
    add_log_options(parser)  # --model, --rigid-body, --robot, --tool, --topic, --cutoff, --rate, --max-gap


def main(args: argparse.Namespace) -> int:
    from franka_vs_gym.errors import UserError
    from franka_vs_gym.validation.app.server import run
    from franka_vs_gym.validation.app.state import App, Options

    if not 0 < args.port < 65536:
        raise UserError(f"--port must be in 1..65535, got {args.port}")
    if args.log is not None and not Path(args.log).exists():
        raise FileNotFoundError(2, "No such file or directory", args.log)
    if args.model is not None and not Path(args.model).is_file():
        raise FileNotFoundError(2, "No such file", args.model)
    app = App(Options(model=args.model, tool=args.tool, robot=args.robot, topic=args.topic,
                      rigid_body=args.rigid_body,
                      settings=CleanSettings(rate=args.rate, cutoff=args.cutoff, max_gap=args.max_gap)))
    if args.log is not None:
        app.open(args.log)  # on the worker thread, while the server starts and the browser connects
    try:
        run(app, args.host, args.port, not args.no_browser)
    except KeyboardInterrupt:
        print("franka-vs workbench: stopped")
    return 0
