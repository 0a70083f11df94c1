"""Drives ``franka-vs workbench`` in Debian's headless chromium through selenium (tests/test_workbench_browser.py and
scripts/workbench_timing.py): starts the command, opens its page, sets widgets through the page's Bokeh models or
clicks its buttons, reads what it shows, and lists every request the page made (to fail on one outside the
machine)."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHROMIUM = next((p for p in ("/usr/bin/chromium", "/usr/bin/chromium-browser") if os.path.exists(p)), None)
CHROMEDRIVER = shutil.which("chromedriver") or ("/usr/bin/chromedriver" if os.path.exists("/usr/bin/chromedriver")
                                                else None)
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage")


def why_skip() -> str | None:
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install selenium)"
    if CHROMIUM is None:
        return "no chromium browser at /usr/bin/chromium (Debian: apt-get install chromium)"
    if CHROMEDRIVER is None:
        return "no chromedriver (Debian: apt-get install chromium-driver)"
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_workbench(log: str | None, port: int, *extra: str, cwd: str | None = None) -> subprocess.Popen:
    """``franka-vs workbench [LOG] --no-browser --port PORT`` in a new process (this interpreter, this package)."""
    cmd = [sys.executable, "-m", "franka_vs_gym.cli", "workbench"] + ([log] if log else []) + [
        "--no-browser", "--port", str(port), *extra]
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parent.parent)
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def stop(proc: subprocess.Popen) -> str:
    proc.terminate()
    try:
        out, _ = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out or ""


def make_browser(width: int = 1400, height: int = 1200, *, performance_log: bool = True,
                 page_load_timeout: float | None = 90):
    """Headless chromium through chromedriver, with its own profile (removed by :func:`quit_browser`); the
    performance log lists every request the page made."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="franka-vs-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for f in FLAGS:
        opts.add_argument(f)
    opts.add_argument(f"--user-data-dir={profile}")
    opts.add_argument(f"--window-size={width},{height}")
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL", **({"performance": "ALL"} if performance_log else {})})
    drv = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
    drv._profile = profile
    if page_load_timeout is not None:
        drv.set_page_load_timeout(page_load_timeout)
    return drv


def quit_browser(drv) -> None:
    drv.quit()
    shutil.rmtree(getattr(drv, "_profile", ""), ignore_errors=True)


MODEL = "const d = (window.Bokeh && Bokeh.documents && Bokeh.documents[0]); " \
        "const m = d ? d.get_model_by_name(arguments[0]) : null;"


def get(drv, name: str, prop: str):
    """A property of the page's model named ``name`` (None while the page has not loaded)."""
    return drv.execute_script(MODEL + f" return m ? m.{prop} : null;", name)


def set_(drv, name: str, prop: str, value) -> None:
    """Set a widget's property in the page, as the user's typing or clicking does (synced to the server)."""
    ok = drv.execute_script(MODEL + f" if (!m) return false; m.{prop} = arguments[1]; return true;", name, value)
    if not ok:
        raise AssertionError(f"no model named {name!r} in the page")


def click(drv, label: str) -> None:
    """Click the button whose text is ``label`` (inside the plotting library's shadow roots)."""
    n = drv.execute_script("""
        const acc = [], label = arguments[0];
        function walk(n) { if (!n) return; if (n.tagName === 'BUTTON' && n.textContent.trim() === label)
          acc.push(n); if (n.shadowRoot) walk(n.shadowRoot); for (const c of n.children || []) walk(c); }
        walk(document.body); if (acc.length) acc[0].click(); return acc.length;""", label)
    if not n:
        raise AssertionError(f"no button {label!r} in the page")


def wait(fn, timeout: float, what: str, every: float = 0.05):
    t0 = time.time()
    while time.time() - t0 < timeout:
        v = fn()
        if v:
            return v
        time.sleep(every)
    raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")


def heldout(drv) -> tuple[float, float] | None:
    """(baseline, enabled) total held-out RMSE the page shows, Nm."""
    import re

    text = get(drv, "heldout", "text") or ""
    m = re.search(r"data-total='([0-9.eE+-]+)' data-baseline='([0-9.eE+-]+)'", text)
    return (float(m.group(2)), float(m.group(1))) if m else None


def open_page(drv, port: int, timeout: float = 120.0) -> float:
    """Load the page (retrying until the server answers) and wait for the first complete document: the residual
    plots with data, the toggles and the held-out error. Returns the seconds it took."""
    from selenium.common.exceptions import WebDriverException

    t0 = time.time()
    url = f"http://127.0.0.1:{port}/"

    def loaded():
        try:
            drv.get(url)
        except WebDriverException:
            return False
        return "workbench" in (drv.title or "")

    wait(loaded, timeout, "the server to answer", every=0.05)
    wait(lambda: heldout(drv) is not None and (get(drv, "f_time", "renderers.length") or 0) > 0
         and get(drv, "toggle_payload", "disabled") is False
         and drv.execute_script(MODEL.replace("arguments[0]", "'toggles'") + " return m ? m.children.length : 0;")
         > 3, timeout, "the residual, the toggles and the held-out error")
    return time.time() - t0


def requests(drv) -> list[str]:
    """Every URL the page requested or opened a web socket to (from chromium's performance log)."""
    out = []
    for e in drv.get_log("performance"):
        m = json.loads(e["message"])["message"]
        if m["method"] == "Network.requestWillBeSent":
            out.append(m["params"]["request"]["url"])
        elif m["method"] == "Network.webSocketCreated":
            out.append(m["params"]["url"])
    return out


def outside(urls: list[str], port: int) -> list[str]:
    """The network requests (any http, https, ws, wss or ftp URL) that go anywhere but the workbench's server on
    127.0.0.1 (data: and blob: URLs are the page's own bytes; chrome:// pages are the browser's own new tab)."""
    ok = (f"http://127.0.0.1:{port}/", f"ws://127.0.0.1:{port}/")
    net = ("http:", "https:", "ws:", "wss:", "ftp:")
    return [u for u in urls if u.lower().startswith(net) and not u.startswith(ok)]


def console_errors(drv) -> list[str]:
    return [e["message"] for e in drv.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]


TOGGLE_TIMER = """
const done = arguments[arguments.length - 1];
const d = Bokeh.documents[0];
const g = d.get_model_by_name(arguments[0]);
const held = d.get_model_by_name('heldout');
const col = (s, k) => (s.data instanceof Map ? s.data.get(k) : s.data[k]);
const src = d.get_model_by_name('f_time').renderers.find(r => r.data_source &&
                                                             col(r.data_source, 'cur') !== undefined).data_source;
const before = held.text, beforeSrc = col(src, 'cur');
const t0 = performance.now();
g.active = arguments[1];
const timer = setInterval(() => {
  if (held.text !== before && col(src, 'cur') !== beforeSrc) {
    clearInterval(timer);
    requestAnimationFrame(() => done(performance.now() - t0));
  } else if (performance.now() - t0 > 30000) { clearInterval(timer); done(-1); }
}, 2);
"""


def time_toggle(drv, name: str, active: list[int]) -> float:
    """Seconds from setting toggle ``name`` to ``active`` until the page shows the new held-out error and residual
    (and has painted a frame after them)."""
    drv.set_script_timeout(60)
    ms = drv.execute_async_script(TOGGLE_TIMER, name, active)
    if ms < 0:
        raise AssertionError(f"the page did not update within 30 s of toggling {name}")
    return ms / 1000.0
