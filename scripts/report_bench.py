"""Size and time of ``--report`` (report.html, report.md and its PNGs) and ``--mcap`` for compare, diagnose and fit.

    python scripts/report_bench.py LOG [--runs 3] [--add payload] [--kinds compare,diagnose,fit]

The results (comparison with the replay, diagnosis, fit) are computed once; each writer then runs in a fresh forked
child that has not imported matplotlib, Bokeh or mcap yet, as a ``franka-vs ... --report`` process would (the import
time is part of the cost a user waits for). Prints per kind and writer the median over ``--runs`` of wall and CPU
seconds and the size written. Pin it to one core for comparable numbers: ``taskset -c 0 python scripts/...``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _size(p: Path) -> int:
    if p.is_dir():
        return sum(f.stat().st_size for f in p.rglob("*") if f.is_file())
    return p.stat().st_size if p.exists() else 0


def _cpu() -> float:
    """CPU seconds of this process and of its children that ended (a writer's own helper process included)."""
    import resource

    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _timed_child(fn) -> dict:
    """Run fn() in a forked child; return its wall and CPU seconds (and what fn returned)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:  # child
        os.close(r)
        out = {}
        try:
            t0, c0 = time.perf_counter(), _cpu()
            extra = fn() or {}
            out = {"wall": time.perf_counter() - t0, "cpu": _cpu() - c0, **extra}
        except BaseException as e:  # report, never hang the parent
            out = {"error": f"{type(e).__name__}: {e}"}
        os.write(w, json.dumps(out).encode())
        os.close(w)
        os._exit(0)
    os.close(w)
    chunks = []
    while True:
        b = os.read(r, 65536)
        if not b:
            break
        chunks.append(b)
    os.close(r)
    os.waitpid(pid, 0)
    out = json.loads(b"".join(chunks) or b"{}")
    if "error" in out:
        raise RuntimeError(out["error"])
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--add", default="payload", help="effects the fit adds (default payload)")
    ap.add_argument("--kinds", default="compare,diagnose,fit")
    ap.add_argument("--writers", default="report,html,markdown,mcap",
                    help="report (html + markdown, one after the other), html, markdown, mcap, views (what "
                         "'--report DIR' does in the command: report.md and its PNGs in a second process where a "
                         "second CPU is free)")
    args = ap.parse_args(argv)

    from franka_vs_gym.validation.compare import compare
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.fitting import fit_effects
    from franka_vs_gym.validation.loading import load_log

    log = load_log(args.log)
    kinds = args.kinds.split(",")
    runs: dict[str, tuple] = {}
    t0 = time.perf_counter()
    if "compare" in kinds:
        runs["compare"] = (compare(log, None), {})
    if "diagnose" in kinds:
        d = diagnose(log, None)
        runs["diagnose"] = (compare(d.data, d.config, do_replay=False), {"diagnosis": d})
    if "fit" in kinds:
        f = fit_effects(log, args.add.split(","), None, holdout=0.25)
        runs["fit"] = (compare(f.data, f.after, do_replay=False), {"fit": f})
    print(f"results computed in {time.perf_counter() - t0:.1f} s; imported before writing: "
          f"{[m for m in ('matplotlib', 'bokeh', 'mcap') if m in sys.modules] or 'none of matplotlib, bokeh, mcap'}")
    print(f"load average before: {os.getloadavg()}; CPUs this process may use: {len(os.sched_getaffinity(0))}")
    tmp = Path(tempfile.mkdtemp(prefix="report-bench-"))
    rows = []
    try:
        for kind, (res, kw) in runs.items():
            for writer in args.writers.split(","):
                walls, cpus, sizes = [], [], []
                for k in range(args.runs):
                    dest = tmp / f"{kind}-{writer}-{k}"

                    def work(res=res, kw=kw, writer=writer, dest=dest):
                        from franka_vs_gym.validation import report

                        if writer == "views":
                            from franka_vs_gym.validation.cli_common import write_views

                            dest.mkdir()
                            write_views(res, dest, None, verbose=False, **kw)
                        elif writer == "report":
                            dest.mkdir()
                            report.markdown_report(res, dest, **kw)
                            report.html_report(res, dest, **kw)
                        elif writer == "html":
                            dest.mkdir()
                            report.html_report(res, dest, **kw)
                        elif writer == "markdown":
                            dest.mkdir()
                            report.markdown_report(res, dest, **kw)
                        else:
                            dest = dest.with_suffix(".mcap")
                            report.write_mcap(dest, res, **kw)
                        return {"size": _size(dest)}

                    out = _timed_child(work)
                    walls.append(out["wall"])
                    cpus.append(out["cpu"])
                    sizes.append(out["size"])
                rows.append((kind, writer, float(np.median(walls)), float(np.median(cpus)), int(np.median(sizes))))
                print(f"{kind:9s} {writer:9s} wall {rows[-1][2]:6.2f} s  CPU {rows[-1][3]:6.2f} s  "
                      f"size {rows[-1][4] / 1e6:6.2f} MB   (runs: {', '.join(f'{w:.2f}' for w in walls)})",
                      flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"load average after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
