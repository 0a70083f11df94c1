"""The workbench server's state, shared by the pages it serves: the opened log, its diagnosis, the saved models,
validations and overlays, and one worker thread for the long jobs (opening, diagnosing, saving) with their progress
and errors. Pages poll :attr:`App.version` and redraw what changed; a toggle is computed in the page's own callback
(one small solve) and never waits for the worker."""

from __future__ import annotations

import sys
import threading
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

from franka_vs_gym.errors import is_user_error, one_line
from franka_vs_gym.validation.app import session as S


@dataclass
class Options:
    """What the command line chose for every log the page opens (as ``compare``/``diagnose``/``fit`` take them)."""

    model: str | None = None
    tool: str | None = None
    robot: str | None = None
    topic: str | None = None
    rigid_body: bool = False
    settings: Any = None


@dataclass
class App:
    options: Options = field(default_factory=Options)
    opened: S.Opened | None = None
    diagnosis: Any = None
    status: str = "no log opened yet: type its path (or pick it from the folder's files) and press 'open'"
    error: str = ""
    busy: bool = False
    version: int = 0
    saved_models: list[str] = field(default_factory=list)
    saved_reports: list[str] = field(default_factory=list)
    validations: list[S.Validation] = field(default_factory=list)
    overlays: list[S.Overlay] = field(default_factory=list)
    last_fit: Any = None  # the FitResult of the last saved model
    arm: Any = None  # the pages' one ArmView (made by the first page)
    page_ready: threading.Event = field(default_factory=threading.Event)  # a page shows the opened log
    stopping: threading.Event = field(default_factory=threading.Event)  # the server is stopping: jobs end
    log_version: int = 0  # increases with each newly opened log (pages rebuild the toggles)
    _pool: ThreadPoolExecutor = field(default_factory=lambda: ThreadPoolExecutor(1, thread_name_prefix="workbench"))
    _lock: threading.Lock = field(default_factory=threading.Lock)
    #: the pages' interval computations (a thread of their own: they never wait for a diagnosis or a save)
    interval_pool: ThreadPoolExecutor = field(default_factory=lambda: ThreadPoolExecutor(1, thread_name_prefix="ci"))

    def _set(self, **kw) -> None:
        with self._lock:
            for k, v in kw.items():
                setattr(self, k, v)
            self.version += 1

    def progress(self, msg: str) -> None:
        self._set(status=msg)

    def submit(self, label: str, work: Callable[[], Any], done: Callable[[Any], None] | None = None) -> None:
        """Run ``work()`` on the worker thread, its stages shown as the status; its result to ``done``; a user's
        error as the CLI's one line (``error: ...``), anything else with its traceback on the terminal."""

        def run() -> None:
            self._set(busy=True, error="", status=f"{label}...")
            try:
                out = work()
            except Exception as e:  # shown in the page; a bug also on the terminal with its traceback
                if is_user_error(e):
                    self._set(busy=False, error=f"error: {one_line(e)}", status=f"{label}: failed")
                else:
                    traceback.print_exc(file=sys.stderr)
                    self._set(busy=False, error=f"internal error (a bug; traceback on the terminal): "
                                                f"{type(e).__name__}: {one_line(e)}", status=f"{label}: failed")
                return
            if done is not None:
                done(out)
            self._set(busy=False)

        self._pool.submit(run)

    def stop(self) -> None:
        """End the jobs: the queued ones are cancelled, a running diagnosis process is stopped."""
        self.stopping.set()
        self.page_ready.set()
        self._pool.shutdown(wait=False, cancel_futures=True)
        self.interval_pool.shutdown(wait=False, cancel_futures=True)

    # --- the jobs
    def open(self, path: str) -> None:
        o = self.options

        def work():
            return S.open_log(path, model=o.model, tool=o.tool, robot=o.robot, settings=o.settings, topic=o.topic,
                              rigid_body=o.rigid_body, progress=self.progress)

        def done(op: S.Opened) -> None:
            self.page_ready.clear()
            self._set(opened=op, diagnosis=None, overlays=[], log_version=self.log_version + 1,
                      status=f"opened {op.path} in {op.seconds:.1f} s; diagnosing in the background (toggles work "
                             "already)")
            self.diagnose()

        self.submit(f"opening {path}", work, done)

    def diagnose(self) -> None:
        """``diagnose`` on the opened log in a process of its own (started once the first page shows the log, or
        after ``DIAGNOSE_AFTER`` s without a page), its stages shown as the status."""
        op = self.opened
        if op is None:
            return

        def work():
            self.page_ready.wait(DIAGNOSE_AFTER)
            return _in_process(op.path, self.options, self.progress, self.stopping)

        def done(d) -> None:
            if self.opened is op:
                self._set(diagnosis=d, status=f"diagnosis done: selected {', '.join(d.selected) or 'nothing'}")

        self.submit("diagnosing", work, done)


DIAGNOSE_AFTER = 5.0  # s: the diagnosis waits this long for a page to show the opened log first


def _child(path: str, options: dict, queue) -> None:
    S.diagnose_file(path, options, queue.put)


def _in_process(path: str, o: Options, progress: Callable[[str], None], stopping: threading.Event):
    """:func:`session.diagnose_file` in a spawned process (no shared GIL with the server), relaying its stages."""
    import multiprocessing as mp
    import queue as q

    ctx = mp.get_context("spawn")
    qu = ctx.Queue()
    opts = {"model": o.model, "tool": o.tool, "robot": o.robot, "topic": o.topic, "rigid_body": o.rigid_body,
            "settings": o.settings}
    proc = ctx.Process(target=_child, args=(path, opts, qu), daemon=True)
    proc.start()
    try:
        while True:
            try:
                kind, val = qu.get(timeout=1.0)
            except q.Empty:
                if stopping.is_set():
                    raise RuntimeError("the server stopped before the diagnosis finished") from None
                if not proc.is_alive():
                    raise RuntimeError("the diagnosis process ended without a result (exit code "
                                       f"{proc.exitcode})") from None
                continue
            if kind == "progress":
                progress(val)
            elif kind == "error":
                raise val
            else:
                return val
    finally:
        proc.join(timeout=5)
        if proc.is_alive():
            proc.terminate()


__all__ = ["App", "Options"]
