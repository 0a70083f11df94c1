"""The ``franka-vs`` command.

Each subcommand lives in its own module, imported only when that subcommand runs (so ``franka-vs diagnose`` does
not pay for rendering or RL imports). A module provides ``add_arguments(parser)`` and ``main(args) -> int``.

Exit status: 0 on success; 2 for a user's mistake (bad option, file or value: one line
``franka-vs <command>: error: <message>`` on stderr, no traceback; see :mod:`franka_vs_gym.errors`); 130 when
interrupted (Ctrl-C or SIGTERM: one line, the unfinished run folder renamed ``...-incomplete`` or removed). Any
other exception is a bug and shows its traceback. No command writes over a file it reads
(:func:`franka_vs_gym.io.command_scope`).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import signal
import sys

from franka_vs_gym import io
from franka_vs_gym.errors import Interrupted, is_user_error, one_line

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("franka_vs_gym.experiments.demo",
             "main job: run a demo on the simulated FER (torque motion, or IBVS/PBVS visual servoing) into runs/"),
    "experiment": ("franka_vs_gym.experiments.cli",
                   "FrankaSim paper experiments: 'tracking' (IV-A) and 'dual-arm' (IV-B)"),
    "compare": ("franka_vs_gym.validation.cli_compare", "compare a model with a measurement log"),
    "diagnose": ("franka_vs_gym.validation.cli_diagnose", "find which physical effect a model lacks on a log"),
    "fit": ("franka_vs_gym.validation.cli_fit", "fit effects on a log and save a calibrated model file"),
    "workbench": ("franka_vs_gym.validation.cli_workbench", "the workbench in the browser: see where the model fails, "
                  "toggle effects, watch the held-out error, save the calibrated model (a local server)"),
    "excite": ("franka_vs_gym.validation.cli_excite", "design the motion to record next (excitation for the effects "
               "in question) with pylibfranka and franky scripts that play and record it"),
    "evaluate": ("franka_vs_gym.envs.cli_evaluate", "evaluate a scripted policy or an SB3 model on an environment"),
    "diagnose-folder": ("franka_vs_gym.scale", "diagnose (and fit) every log of a folder in parallel on Ray "
                        "(local or a cluster)"),
    "serve": ("franka_vs_gym.fci.cli", "serve the simulated FER on libfranka's network interface (FCI)"),
}


def version_line() -> str:
    """``franka-vs X (mujoco Y, pinocchio Z, Python V)``: the package and the versions its results depend on."""
    from importlib.metadata import PackageNotFoundError, version

    from franka_vs_gym import __version__

    def ver(dist: str) -> str:
        try:
            return version(dist)
        except PackageNotFoundError:
            return "not installed"

    py = ".".join(map(str, sys.version_info[:3]))
    return f"franka-vs {__version__} (mujoco {ver('mujoco')}, pinocchio {ver('pin')}, Python {py})"


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="franka-vs", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=version_line())
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_) in COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        if name == command:
            importlib.import_module(module).add_arguments(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in argv if not a.startswith("-")), None)
    if command is not None and command not in COMMANDS:
        build_parser().error(f"unknown command {command!r} (choose from {', '.join(COMMANDS)})")
    parser = build_parser(command)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    module = importlib.import_module(COMMANDS[args.command][0])
    with _sigterm_as_interrupt(), io.command_scope():
        try:
            return int(module.main(args) or 0)
        except KeyboardInterrupt:
            notes = io.abandon_runs()
            print(f"franka-vs {args.command}: interrupted" + (f"; {'; '.join(notes)}" if notes else ""),
                  file=sys.stderr)
            return 130
        except Exception as e:
            notes = io.abandon_runs()  # an unfinished run folder is renamed ...-incomplete, never left as if done
            if not is_user_error(e):
                if notes:
                    print(f"franka-vs {args.command}: {'; '.join(notes)}", file=sys.stderr)
                raise
            print(f"franka-vs {args.command}: error: {one_line(e)}" + (f" ({'; '.join(notes)})" if notes else ""),
                  file=sys.stderr)
            return 2


def _raise_interrupted(signum: int, frame: object) -> None:
    raise Interrupted(f"signal {signum}")


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """SIGTERM stops the command like Ctrl-C, and Ctrl-C (SIGINT) always does (only in the main thread, where
    handlers can be installed). A process inherits an ignored SIGINT from its parent: a shell script's background
    job (``franka-vs serve &``) or a test runner's worker; Python then installs no handler and ``kill -INT`` would
    be lost, so the command installs Python's own handler for its duration."""
    try:
        old = signal.signal(signal.SIGTERM, _raise_interrupted)
    except ValueError:  # not the main thread
        yield
        return
    old_int = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)
        signal.signal(signal.SIGINT, old_int)


if __name__ == "__main__":
    sys.exit(main())
