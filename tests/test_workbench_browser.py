"""``franka-vs workbench`` in a real headless browser (Debian's chromium through selenium): open a log with a hidden
payload, switch the effects off, toggle the payload on and see the held-out error fall, get the CLI's one-line error
for a bad path, save the calibrated model (and be refused when saving over it), read it with ``franka-vs compare
--model``, validate it on a second log; the page requests nothing outside 127.0.0.1 and logs no console error.

Set FRANKA_VS_SCREENSHOTS=DIR to save a screenshot of the page. Skips, saying why, where selenium, chromium or
chromedriver is missing (Debian: apt-get install chromium chromium-driver; selenium from PyPI).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
from pathlib import Path

import numpy as np
import pytest
import workbench_driver as W

from franka_vs_gym.cli import main as cli
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.logs import save_log

pytestmark = pytest.mark.skipif(W.why_skip() is not None, reason=W.why_skip() or "")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wbbrowser")
    log, answer = make_hidden_effect_log("payload", 3, duration=10.0)
    second, _ = make_hidden_effect_log("payload", 3, duration=6.0)  # the same hidden payload, a shorter run
    return save_log(log, tmp / "payload.npz"), save_log(second, tmp / "second.npz"), answer, tmp


def test_workbench_loop_in_the_browser(logs):
    log, second, answer, tmp = logs
    port = W.free_port()
    proc = W.start_workbench(str(log), port, cwd=str(tmp))
    drv = W.make_browser()
    try:
        W.open_page(drv, port)
        # the diagnosis arrives in the background and presets its selection (the payload)
        W.wait(lambda: "verdict" in (W.get(drv, "diagnosis", "text") or ""), 300, "the diagnosis")
        assert "payload" in W.get(drv, "diagnosis", "text")
        W.click(drv, "none")
        W.wait(lambda: (h := W.heldout(drv)) and abs(h[0] - h[1]) < 1e-9, 30, "the effects switched off")
        base, _ = W.heldout(drv)
        dt = W.time_toggle(drv, "toggle_payload", [0])
        base2, with_payload = W.heldout(drv)
        assert base2 == base and with_payload < 0.5 * base, (base, with_payload)
        assert with_payload < 1.25 * float(np.sqrt(np.mean(np.square(answer["torque_noise_Nm"]))))
        assert dt < 30
        assert "payload" in W.get(drv, "params", "text")
        # the enabled set's 95 % intervals follow the toggle
        W.wait(lambda: "with 95 % intervals" in (W.get(drv, "params", "text") or ""), 120, "the intervals")
        assert "mass_kg" in W.get(drv, "params", "text") and "(95% [" in W.get(drv, "params", "text")
        arm = W.get(drv, "arm", "text")
        W.wait(lambda: "<img" in (W.get(drv, "arm", "text") or "") or "no arm view" in W.get(drv, "arm", "text"),
               60, "the arm view")
        # a bad path: the CLI's one-line error in the page, the opened log kept
        W.set_(drv, "path", "value", str(tmp / "no_such_log.csv"))
        W.click(drv, "open")
        W.wait(lambda: "error:" in (W.get(drv, "error", "text") or ""), 60, "the error line")
        assert "no_such_log.csv" in W.get(drv, "error", "text") and "No such file" in W.get(drv, "error", "text")
        assert W.heldout(drv)[1] == with_payload
        # save the calibrated model under a new name, then be refused over it (nothing overwritten)
        out = tmp / "saved-model.json"
        W.set_(drv, "model_out", "value", str(out))
        W.click(drv, "save model")
        W.wait(lambda: out.exists() and "saved the calibrated model" in (W.get(drv, "status", "text") or ""), 120,
               "the saved model")
        saved = out.read_bytes()
        W.wait(lambda: W.get(drv, "model_out", "value") != str(out), 30, "a new name proposed")
        W.set_(drv, "model_out", "value", str(out))  # the saved file's name typed again
        W.click(drv, "save model")
        W.wait(lambda: "choose a new name" in (W.get(drv, "error", "text") or ""), 60, "the refusal")
        assert out.read_bytes() == saved
        # the saved model is fit's file: franka-vs compare --model reads it
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            assert cli(["compare", str(second), "--model", str(out), "--no-replay", "--json", "--quiet"]) == 0
        rm = np.array(json.loads(buf.getvalue())["rmse_tau"])
        assert np.all(rm < 1.3 * np.array(answer["torque_noise_Nm"]) + 0.02), rm
        # validation on the second log in the page
        W.set_(drv, "val_log", "value", str(second))
        W.set_(drv, "val_model", "value", str(out))
        W.click(drv, "validate")
        W.wait(lambda: "second.npz: RMSE" in (W.get(drv, "saved", "text") or ""), 120, "the validation")
        assert not W.console_errors(drv), W.console_errors(drv)
        urls = W.requests(drv)
        assert any(u.startswith(f"ws://127.0.0.1:{port}/") for u in urls), urls
        assert W.outside(urls, port) == [], W.outside(urls, port)
        shots = os.environ.get("FRANKA_VS_SCREENSHOTS")
        if shots:
            Path(shots).mkdir(parents=True, exist_ok=True)
            drv.set_window_size(1400, 2700)
            drv.save_screenshot(str(Path(shots) / "workbench_app.png"))
        del arm
    finally:
        W.quit_browser(drv)
        W.stop(proc)
