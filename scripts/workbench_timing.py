"""Time ``franka-vs workbench LOG`` in headless chromium: from the command to the first complete document (the
residual plots with data, the toggles and the held-out error on the page), and from a toggle to the updated page
(the new held-out error and residual received and a frame painted), on a 30 s, 1 kHz log with a hidden payload.

    python scripts/workbench_timing.py [--log LOG] [--toggles 10] [--json]

The browser is started first (its own start-up is not counted); the clock starts when the command is launched.
Toggles are timed in the page (``performance.now()`` from setting the toggle's state, as a click does, to the frame
after the update), both while the diagnosis still runs in the background and after it. The machine's load average
is printed beside the numbers (the project's machine is shared), with the CPU seconds the server and the browser
spent until the page was usable: what the wall time would approach on an idle machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import workbench_driver as W  # noqa: E402


def cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of process ``pid`` so far (Linux /proc)."""
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")


def browser_cpu_seconds(profile: str) -> float:
    """CPU seconds of every chromium process started with ``profile`` (its user-data-dir)."""
    total = 0.0
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if profile.encode() in (d / "cmdline").read_bytes():
                total += cpu_seconds(int(d.name))
        except OSError:
            continue
    return total


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--log", default=None, help="the log (default: a 30 s, 1 kHz log with a hidden payload)")
    ap.add_argument("--toggles", type=int, default=10, help="toggles timed after the diagnosis (default 10)")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args()
    why = W.why_skip()
    if why:
        print(f"workbench_timing: cannot run: {why}", file=sys.stderr)
        return 2
    tmp = Path(tempfile.mkdtemp(prefix="wb-timing-"))
    log = a.log
    if log is None:
        from franka_vs_gym.validation.hidden import make_hidden_effect_log
        from franka_vs_gym.validation.logs import save_log

        lg, _ = make_hidden_effect_log("payload", 3, duration=30.0)
        log = str(save_log(lg, tmp / "payload_30s.npz"))
    port = W.free_port()
    drv = W.make_browser()
    drv.get("about:blank")
    load0 = os.getloadavg()[0]
    b0 = browser_cpu_seconds(drv._profile)
    t0 = time.time()
    proc = W.start_workbench(log, port, cwd=str(tmp))
    listening = []
    import threading

    threading.Thread(target=lambda: (proc.stdout.readline(), listening.append(time.time() - t0)), daemon=True).start()
    try:
        W.open_page(drv, port, timeout=300)
        usable = time.time() - t0
        cpu_server, cpu_browser = cpu_seconds(proc.pid), browser_cpu_seconds(drv._profile) - b0
        import re

        m = re.search(r"opened-s'>([0-9.]+)<", W.get(drv, "title", "text") or "")
        during = []
        diag_done = lambda: "verdict" in (W.get(drv, "diagnosis", "text") or "")  # noqa: E731
        state = [0]
        while not diag_done() and len(during) < 3:
            state[0] = 1 - state[0]
            during.append(W.time_toggle(drv, "toggle_torque_offset", [1, 3] if state[0] else []))
        W.wait(diag_done, 600, "the diagnosis")
        diagnosed = time.time() - t0
        W.click(drv, "none")
        W.wait(lambda: (h := W.heldout(drv)) and abs(h[0] - h[1]) < 1e-12, 60, "the effects switched off")
        after = []
        c0s, c0b = cpu_seconds(proc.pid), browser_cpu_seconds(drv._profile)
        names = ("toggle_payload", "toggle_sigmoid_friction", "toggle_payload", "toggle_sigmoid_friction")
        on = {n: False for n in names}
        for i in range(a.toggles):
            n = names[i % len(names)]
            on[n] = not on[n]
            after.append(W.time_toggle(drv, n, ([0] if n == "toggle_payload" else list(range(7))) if on[n] else []))
        n_t = max(len(after), 1)
        cpu_toggle = [(cpu_seconds(proc.pid) - c0s) / n_t, (browser_cpu_seconds(drv._profile) - c0b) / n_t]
        h = W.heldout(drv)
        urls = W.requests(drv)
        out = {"log": log, "seconds_to_usable_page": round(usable, 2),
               "cpu_s_to_usable_page_server_browser": [round(cpu_server, 2), round(cpu_browser, 2)],
               "seconds_to_server_listening": round(listening[0], 2) if listening else None,
               "seconds_opening_the_log_in_the_server": float(m.group(1)) if m else None,
               "seconds_to_diagnosis": round(diagnosed, 2),
               "toggle_s_during_diagnosis": [round(x, 3) for x in during],
               "toggle_s": [round(x, 3) for x in after],
               "toggle_s_median": round(statistics.median(after), 3) if after else None,
               "toggle_s_max": round(max(after), 3) if after else None,
               "cpu_s_per_toggle_server_browser": [round(x, 3) for x in cpu_toggle],
               "heldout_total_Nm_baseline_last": [round(x, 4) for x in h],
               "outside_requests": W.outside(urls, port), "loadavg_1min_before_after": [load0, os.getloadavg()[0]],
               "cpus": len(os.sched_getaffinity(0))}
    finally:
        W.quit_browser(drv)
        W.stop(proc)
    if a.json:
        print(json.dumps(out))
    else:
        for k, v in out.items():
            print(f"{k}: {v}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
