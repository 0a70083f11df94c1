"""report.html in a real headless browser (Debian's chromium driven by selenium through /usr/bin/chromedriver): every
plot renders with data, switching the joint swaps the data in, and the page logs no console error.

Set FRANKA_VS_SCREENSHOTS=DIR to save screenshots of the report (docs/images/ is where the docs take them from).
Skips, saying why, where selenium, chromium or chromedriver is not installed (Debian: apt-get install chromium
chromium-driver; selenium from PyPI).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest
from workbench_driver import make_browser, quit_browser  # one definition of the browser both tests drive
from workbench_driver import why_skip as _why_skip

from franka_vs_gym.cli import main as cli
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.logs import save_log

pytestmark = pytest.mark.skipif(_why_skip() is not None, reason=_why_skip() or "")


@pytest.fixture(scope="module")
def browser():
    drv = make_browser(1280, 1000, performance_log=False, page_load_timeout=None)
    try:
        yield drv
    finally:
        quit_browser(drv)


@pytest.fixture(scope="module")
def reports(tmp_path_factory) -> dict[str, Path]:
    """compare (with the replay), diagnose and fit reports of a log with two hidden effects (viscous friction and a
    gravity tilt)."""
    tmp = tmp_path_factory.mktemp("browser")
    log, _ = make_hidden_effect_log("viscous_friction+gravity_tilt", 3, duration=8.0)
    p = save_log(log, tmp / "two_effects.npz")
    assert cli(["diagnose", str(p), "--report", str(tmp / "diag"), "--quiet"]) == 0
    assert cli(["fit", str(p), "--add", "viscous_friction,gravity_tilt", "-o", str(tmp / "cal.json"), "--report",
                str(tmp / "fit"), "--quiet"]) == 0
    assert cli(["compare", str(p), "--report", str(tmp / "cmp"), "--quiet"]) == 0
    # a designed excitation: identify a payload and tell viscous friction from a delay (a short search)
    assert cli(["excite", "--effects", "payload", "--separate", "viscous_friction,delay", "--duration", "8",
                "--rest", "0.5", "--evaluations", "30", "-o", str(tmp / "next"), "--report", str(tmp / "exc"),
                "--quiet"]) == 0
    return {"diagnose": tmp / "diag" / "report.html", "fit": tmp / "fit" / "report.html",
            "compare": tmp / "cmp" / "report.html", "excite": tmp / "exc" / "report.html"}


# per rendered plot: its title, how many glyph renderers, how many data points each displays
PLOT_STATE = """
const out = [];
for (const doc of Bokeh.documents) {
  for (const m of doc._all_models.values()) {
    if (m.renderers === undefined || m.x_range === undefined || m.title === undefined) continue;
    const counts = [];
    for (const r of m.renderers) {
      if (!r.data_source) continue;
      const src = r.data_source;
      const key = src.data instanceof Map ? src.data.keys().next().value : Object.keys(src.data)[0];
      const col = key === undefined ? [] : (src.data instanceof Map ? src.data.get(key) : src.data[key]);
      counts.push(col.length);
    }
    out.push({title: m.title ? m.title.text : "", visible: m.visible, counts: counts});
  }
}
return out;
"""

CANVAS_INK = """
// fraction of non-white pixels in every plot canvas (a plot that drew data has ink beyond its frame)
const out = [];
function walk(node, acc) {
  if (!node) return;
  if (node.tagName === "CANVAS") acc.push(node);
  if (node.shadowRoot) walk(node.shadowRoot, acc);
  for (const c of node.children || []) walk(c, acc);
}
const canvases = [];
walk(document.body, canvases);
for (const c of canvases) {
  if (c.width < 200 || c.height < 150) continue;
  const ctx = c.getContext("2d");
  const d = ctx.getImageData(0, 0, c.width, c.height).data;
  let ink = 0;
  for (let i = 0; i < d.length; i += 16) { if (d[i] < 200 || d[i + 1] < 200 || d[i + 2] < 200) ink++; }
  out.push(ink / (d.length / 16));
}
return out;
"""


def _load(browser, path: Path):
    browser.get(path.as_uri())
    t0 = time.time()
    while time.time() - t0 < 60:
        n = browser.execute_script("return (window.Bokeh && Bokeh.documents) ? Bokeh.documents.length : 0")
        if n:
            break
        time.sleep(0.2)
    time.sleep(1.0)  # let the canvases paint


def _joint_buttons(browser):
    """The report's joint selector buttons (inside the plotting library's shadow roots)."""
    return browser.execute_script("""
        const acc = [];
        function walk(n) { if (!n) return; if (n.tagName === 'BUTTON' && /^joint [0-6]$/.test(n.textContent.trim()))
          acc.push(n); if (n.shadowRoot) walk(n.shadowRoot); for (const c of n.children || []) walk(c); }
        walk(document.body); return acc;""")


def _errors(browser) -> list[str]:
    return [e["message"] for e in browser.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]


@pytest.mark.parametrize("kind", ["diagnose", "fit", "compare"])
def test_report_renders_every_plot_with_data(kind, reports, browser):
    path = reports[kind]
    assert path.stat().st_size < 5e6
    _load(browser, path)
    assert browser.execute_script("return typeof Bokeh") == "object", "Bokeh did not load from the file"
    plots = browser.execute_script(PLOT_STATE)
    # RMSE bars, torque, residual, follows, and the effects' torques (diagnose, fit) or the replay (compare)
    assert len(plots) >= 5, plots
    for p in plots:
        assert p["counts"] and max(p["counts"]) > 0, f"plot {p['title']!r} shows no data"
    titles = " ".join(p["title"] for p in plots)
    assert "measured and model torque" in titles and "residual" in titles
    assert ("replay in the MuJoCo plant" in titles) == (kind == "compare")
    ink = browser.execute_script(CANVAS_INK)
    assert len(ink) >= 5 and min(ink) > 0.01, ink  # every plot drew something
    # the joint selector swaps each joint's samples in
    before = {p["title"]: p["counts"] for p in plots}
    buttons = _joint_buttons(browser)
    assert len(buttons) == 7
    shown = next(p["title"] for p in plots if "measured and model torque" in p["title"])
    other = next(b for b in buttons if b.text.strip() not in shown)
    other.click()
    time.sleep(0.5)
    after = browser.execute_script(PLOT_STATE)
    torque = next(p for p in after if "measured and model torque" in p["title"])
    assert other.text.strip() in torque["title"] and max(torque["counts"]) > 0
    assert {p["title"]: p["counts"] for p in after} != before
    assert not _errors(browser), _errors(browser)
    shots = os.environ.get("FRANKA_VS_SCREENSHOTS")
    if shots:
        Path(shots).mkdir(parents=True, exist_ok=True)
        _load(browser, path)
        browser.set_window_size(1280, 1500)
        time.sleep(1.0)
        browser.save_screenshot(str(Path(shots) / f"report_{kind}.png"))
        browser.set_window_size(1280, 1000)


def test_excite_report_renders_motion_limits_and_widths(reports, browser):
    """The designed excitation's report: the motion per joint against its position, velocity and acceleration
    limits and the predicted widths (designed and reference) render with data; the joint selector swaps the joint's
    motion in; the commands to play it are on the page."""
    import json as _json

    path = reports["excite"]
    assert path.stat().st_size < 5e6
    design = _json.loads((path.parent.parent / "next" / "excite.json").read_text())
    _load(browser, path)
    assert browser.execute_script("return typeof Bokeh") == "object", "Bokeh did not load from the file"
    plots = browser.execute_script(PLOT_STATE)
    titles = [p["title"] for p in plots]
    for what in ("position", "velocity", "acceleration"):
        p = next(p for p in plots if f"designed {what} and the robot's limits" in p["title"])
        # the designed trace (thousands of samples, decimated) and the limit lines (5 points: two segments)
        assert len(p["counts"]) >= 3 and max(p["counts"]) > 100 and 5 in p["counts"], (what, p)
    widths = next(p for p in plots if "interval width" in p["title"])
    assert widths["counts"] == [len(design["predicted_ci95_width"])] * 2, widths  # reference and designed bars
    ink = browser.execute_script(CANVAS_INK)
    assert len(ink) >= 4 and min(ink) > 0.01, ink
    buttons = _joint_buttons(browser)
    assert len(buttons) == 7
    shown = next(t for t in titles if "designed position" in t)
    other = next(b for b in buttons if b.text.strip() not in shown)
    other.click()
    time.sleep(0.5)
    after = browser.execute_script(PLOT_STATE)
    pos = next(p for p in after if "designed position" in p["title"])
    assert other.text.strip() in pos["title"] and max(pos["counts"]) > 100
    text = browser.execute_script("return document.body.innerText")
    assert "franka-vs serve" in text and "play_excitation_pylibfranka.py" in text and "ROBOT_ADDRESS" in text
    assert "viscous_friction and delay" in text  # what it tells apart
    assert not _errors(browser), _errors(browser)
    shots = os.environ.get("FRANKA_VS_SCREENSHOTS")
    if shots:
        _load(browser, path)
        browser.set_window_size(1280, 1500)
        time.sleep(1.0)
        browser.save_screenshot(str(Path(shots) / "report_excite.png"))
        browser.set_window_size(1280, 1000)


def test_report_is_self_contained(reports):
    """No network: the page names no http(s) resource to load."""
    import re

    for kind in ("diagnose", "excite"):
        text = reports[kind].read_text()
        loads = re.findall(r'<(?:script|link)[^>]+(?:src|href)="(https?://[^"]+)"', text)
        assert loads == [], kind
        assert np.isfinite(reports[kind].stat().st_size)
