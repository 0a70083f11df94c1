"""Arguments shared by ``franka-vs compare``, ``diagnose`` and ``fit``."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from pathlib import Path

from franka_vs_gym.validation.signals import GAP_FACTOR, CleanSettings


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run a diagnosis or a fit with the BLAS libraries on one thread (``threadpoolctl``): its least-squares
    problems are small and long (tens of columns, thousands of rows), where OpenBLAS's second thread costs more CPU
    than it saves, and on a busy machine much more wall time too (docs/speed_check.md)."""
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1, user_api="blas"):
        yield


def add_common(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="measurement log: CSV or NPZ (with optional <log>.json sidecar), a ROS 1 bag or a "
                                    "ROS 2 bag folder (sqlite3 or MCAP) or .mcap file of Franka robot states or "
                                    "sensor_msgs/JointState, a libfranka "
                                    "logToCSV file, a Gaz et al. 2019 text folder, or a dump of pylibfranka/franky "
                                    "robot states (JSON, JSON lines, CSV, NPZ/NPY, franky pickle; detected from the "
                                    "content)")
    add_log_options(parser)
    parser.add_argument("--report", metavar="DIR", default=None,
                        help="write the report into DIR: report.html (one interactive file, opens offline), "
                             "report.md and PNG figures")
    parser.add_argument("--mcap", metavar="FILE", default=None,
                        help="write the run as an MCAP log (measurement, model, residual, each effect's torque, "
                             "findings) for Foxglove or PlotJuggler")
    parser.add_argument("--force", action="store_true", help="overwrite existing output files")
    parser.add_argument("--quiet", action="store_true", help="no progress on stderr")
    parser.add_argument("--verbose", "-v", action="store_true",
                        help="every stage on its own line, and the details (assumptions, ranking, notes)")


def add_log_options(parser: argparse.ArgumentParser) -> None:
    """How a log is read and which model it is compared with: the options every command that reads a log shares
    (compare, diagnose, fit, workbench)."""
    parser.add_argument("--model", metavar="FILE", default=None,
                        help="calibrated model file (JSON) to compare; default: the FER with the log's declared tool")
    parser.add_argument("--rigid-body", action="store_true",
                        help="start from the model without any joint friction (rigid-body model)")
    parser.add_argument("--robot", default=None,
                        help="the robot the log comes from: a registered name (fer, fr3, ...; default fer)")
    parser.add_argument("--tool", choices=("franka_hand", "none", "unknown"), default=None,
                        help="the tool on the flange (default: what the log declares, else the Franka Hand); "
                             "'unknown' fits the tool's mass, centre of mass and inertia")
    parser.add_argument("--topic", default=None,
                        help="ROS bag: the topic to read, a Franka robot state (franka_msgs FrankaState/"
                             "FrankaRobotState) or sensor_msgs/JointState (default: the Franka state topic, else the "
                             "JointState topic with the seven arm joints and efforts; the choice is stated)")
    parser.add_argument("--cutoff", type=float, default=None,
                        help="zero-phase low-pass cutoff for q and dq, Hz (default 10, or a quarter of the rate for "
                             "logs slower than 40 Hz)")
    parser.add_argument("--rate", type=float, default=None,
                        help="resampling rate, Hz (default: the log's own median rate, at most 1000)")
    parser.add_argument("--max-gap", type=float, default=None, metavar="SECONDS",
                        help=f"longest gap bridged by interpolation, s (default {GAP_FACTOR:g} median sample periods "
                             "of the log, at least 0.05)")


def settings_from(args: argparse.Namespace) -> CleanSettings:
    return CleanSettings(rate=args.rate, cutoff=args.cutoff, max_gap=args.max_gap)


def load_from(args: argparse.Namespace):
    """The log named on the command line, read with the --topic option (a path stays a path when not needed)."""
    from franka_vs_gym.validation.loading import load_log

    return load_log(args.log, topic=args.topic, progress=not getattr(args, "quiet", False),
                    tool=getattr(args, "tool", None))


def stage_views(args: argparse.Namespace, outputs) -> tuple[Path | None, Path | None]:
    """The staged report folder and MCAP file (refused before any work when they exist or are inputs)."""
    report = outputs.folder(args.report, what="report folder") if args.report else None
    mcap = outputs.file(args.mcap, what="MCAP log") if getattr(args, "mcap", None) else None
    return report, mcap


def write_views(res, report_dir: Path | None, mcap_file: Path | None, *, diagnosis=None, fit=None,
                model_file: str | None = None, summary: dict | None = None, verbose: bool = True) -> None:
    """The report (report.html, report.md and figures) and the MCAP log of one run, from its results."""
    from franka_vs_gym.validation import report
    from franka_vs_gym.validation.compare import progress

    join = None
    if report_dir is not None:
        progress("writing the report: report.html, report.md and figures", verbose)
        # report.md and its PNGs (matplotlib) in a second process while this one writes report.html (Bokeh) and the
        # MCAP log, where a second CPU is free
        join = alongside(lambda: report.markdown_report(res, report_dir, diagnosis=diagnosis, fit=fit,
                                                        overwrite=True))
        report.html_report(res, report_dir, diagnosis=diagnosis, fit=fit, model_file=model_file, overwrite=True)
    if mcap_file is not None:
        progress("writing the MCAP log", verbose)
        report.write_mcap(mcap_file, res, diagnosis=diagnosis, fit=fit, summary=summary)
    if join is not None:
        join()


def alongside(work):
    """Run ``work()`` in a forked child while the caller goes on, when this process may use two or more CPUs and
    runs no other thread (a fork copies only the calling thread); else run it here and now. Returns ``join()``: it
    waits for the child, and if the child failed runs ``work()`` here, so that its error is raised as usual (the
    child only ever writes files ``work`` writes anyway)."""
    import os
    import sys
    import threading

    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if not hasattr(os, "fork") or cpus < 2 or threading.active_count() > 1:
        work()
        return lambda: None
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid == 0:  # the child: do the work, exit without running the parent's cleanup or flushing its buffers
        code = 1
        try:
            work()
            code = 0
        finally:
            os._exit(code)

    def join() -> None:
        _, status = os.waitpid(pid, 0)
        if not (os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0):
            work()  # again here: the same result, or the error as the caller would have seen it

    return join


def say_outputs(args: argparse.Namespace) -> list[str]:
    """Where the outputs went, for the terminal."""
    out = []
    if args.report:
        out.append(f"report: {Path(args.report) / 'report.html'} (open in a browser)")
    if getattr(args, "mcap", None):
        out.append(f"MCAP log: {args.mcap} (Foxglove, PlotJuggler)")
    return out


def carried_flags(args: argparse.Namespace, after_fit: bool = False) -> str:
    """The options of this run that the suggested next command needs too, as command-line text: how the log is
    read and processed (``--topic``, ``--rate``, ``--cutoff``, ``--max-gap``), the robot, and, before a fit, the
    model and the tool (after a fit the calibrated model file holds both)."""
    import shlex

    out = []
    for flag, attr in (("--robot", "robot"), ("--topic", "topic"), ("--rate", "rate"), ("--cutoff", "cutoff"),
                       ("--max-gap", "max_gap")) + (() if after_fit else (("--model", "model"), ("--tool", "tool"))):
        v = getattr(args, attr, None)
        if v is not None:
            out.append(f"{flag} {shlex.quote(str(v))}")
    if not after_fit and getattr(args, "rigid_body", False):
        out.append("--rigid-body")
    return " ".join(out)


def input_paths(args: argparse.Namespace) -> list[Path]:
    """Every file the command reads (the log, its sidecars, the files of a log folder, --model): no output may be
    one of them, whatever --force says."""
    from franka_vs_gym.validation.logs import sidecar_path

    log = Path(args.log)
    paths = [log, sidecar_path(log), log.with_suffix(".json")]
    if log.is_dir():
        paths += [p for p in log.rglob("*") if p.is_file()]
    if getattr(args, "model", None):
        paths.append(Path(args.model))
    return paths
