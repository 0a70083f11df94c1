"""``franka-vs workbench``: the app's computations (the toggle's refit against an independent least-squares fit, the
held-out error falling with the hidden effect, fit %, parameters at their bounds, the saved model read by
``franka-vs compare --model``, nothing overwritten) and the command's bad input. The browser test is in
tests/test_workbench_browser.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from franka_vs_gym.cli import main as cli
from franka_vs_gym.validation.app import session as S
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.logs import save_log


@pytest.fixture(scope="module")
def payload_log(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wbapp")
    log, answer = make_hidden_effect_log("payload", 3, duration=10.0)
    return save_log(log, tmp / "payload.npz"), answer


@pytest.fixture(scope="module")
def opened(payload_log):
    return S.open_log(str(payload_log[0]))


def test_refit_is_the_least_squares_fit_on_the_fit_part(opened):
    """A toggle's refit (the selection engine's solve from cached Gram matrices on the fit part) equals a plain
    least-squares fit of the same columns on the same samples, and its held-out RMSE is that fit's error on the
    held-out samples."""
    op = opened
    enabled = {"payload": None, "torque_offset": [1, 3]}
    r = S.refit(op, enabled)
    P = op.terms["payload"].effect.design(op.ctx, op.terms["payload"].shape)  # (N, 7, 10), shared by the joints
    ones = np.ones((op.ctx.n, 1))
    # one stacked system: the payload's 10 shared columns and an offset column for joints 1 and 3 each
    rows = []
    for j in range(7):
        extra = np.zeros((op.ctx.n, 2))
        if j == 1:
            extra[:, :1] = ones
        if j == 3:
            extra[:, 1:] = ones
        rows.append(np.hstack([P[:, j, :], extra]))
    X = np.stack(rows, axis=1)  # (N, 7, 12)
    tr, te = op.train, op.test
    A = X[tr].transpose(1, 0, 2).reshape(-1, 12)
    b = op.y[tr].T.reshape(-1)
    theta = np.linalg.lstsq(A, b, rcond=None)[0]
    resid = op.y - np.einsum("njp,p->nj", X, theta)
    np.testing.assert_allclose(r.rmse_heldout, np.sqrt(np.mean(resid[te] ** 2, axis=0)), rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(r.residual, resid, atol=1e-6)
    # the split is fit's own: the first 75 % fit, the last 25 % validate
    assert len(tr) == int(round(op.ctx.n * 0.75)) and te[0] == tr[-1] + 1 and te[-1] == op.ctx.n - 1


def test_hidden_payload_toggled_on_lowers_the_held_out_error_to_the_noise(opened, payload_log):
    op, answer = opened, payload_log[1]
    base = S.refit(op, {})
    with_payload = S.refit(op, {"payload": None})
    assert float(np.sum(with_payload.rmse_heldout ** 2)) < 0.2 * float(np.sum(base.rmse_heldout ** 2))
    # what is left is the sensor noise the log was made with (within 25 %)
    np.testing.assert_allclose(with_payload.rmse_heldout, answer["torque_noise_Nm"], rtol=0.25)
    assert abs(with_payload.params["payload"]["mass_kg"] - answer["params"]["mass_kg"]) < 0.05
    assert np.all(with_payload.fit_percent >= base.fit_percent - 1e-9)


def test_fit_percent_is_the_normalised_rmse_fit():
    rng = np.random.default_rng(0)
    y = rng.normal(size=(500, 2)) * [1.0, 3.0] + [5.0, -1.0]
    r = 0.1 * rng.normal(size=(500, 2))
    want = [100 * (1 - np.sqrt(np.sum(r[:, j] ** 2)) / np.sqrt(np.sum((y[:, j] - y[:, j].mean()) ** 2)))
            for j in range(2)]
    np.testing.assert_allclose(S.fit_percent(y, r), want)
    np.testing.assert_allclose(S.fit_percent(y, y - y.mean(axis=0)), [0.0, 0.0], atol=1e-9)


def test_parameters_at_their_bounds_are_named_with_their_interval():
    p = {"phi2_s_per_rad": [2.0, 400.0, None, 10, 10, 10, 10], "phi3_rad_per_s": [0.3, 0, 0, 0, 0, 0, 0],
         "joints": [0, 1, 3]}
    ci = {"phi2_s_per_rad": [[1, 3], [350.0, 400.0], None, None, None, None, None]}
    w = S.bound_warnings("sigmoid_friction", p, ci)
    assert len(w) == 2
    assert "phi2_s_per_rad joint 1 = 400" in w[0] and "[350, 400]" in w[0]
    assert "phi3_rad_per_s joint 0 = 0.3" in w[1]
    assert S.bound_warnings("delay", {"delay_s": 0.05}) == []
    assert "bound 0.1" in S.bound_warnings("delay", {"delay_s": 0.1})[0]


def test_saved_model_is_fits_file_and_nothing_is_overwritten(opened, payload_log, tmp_path):
    op, answer = opened, payload_log[1]
    res = S.calibrate(op, {"payload": None})
    assert res.effects == ["payload"]
    assert abs(res.params["payload"]["mass_kg"] - answer["params"]["mass_kg"]) < 0.05
    assert "payload" in res.params_ci95
    path = S.save_model(op, res, str(tmp_path / "cal.json"))
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="choose a new name"):
        S.save_model(op, res, str(path))
    assert path.read_bytes() == before
    with pytest.raises(FileExistsError):  # the log itself, an input
        S.save_model(op, res, str(payload_log[0]))
    # the file franka-vs fit -o writes: compare --model reads it and the payload's error is gone
    out = tmp_path / "cmp.json"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert cli(["compare", str(payload_log[0]), "--model", str(path), "--no-replay", "--json", "--quiet"]) == 0
    got = json.loads(buf.getvalue())
    out.write_text(buf.getvalue())
    assert np.all(np.array(got["rmse_tau"]) < 1.3 * np.array(answer["torque_noise_Nm"]) + 0.02)


def test_workbench_command_bad_input(tmp_path, capsys):
    assert cli(["workbench", str(tmp_path / "missing.npz"), "--no-browser"]) == 2
    assert "franka-vs workbench: error:" in capsys.readouterr().err
    assert cli(["workbench", "--port", "0", "--no-browser"]) == 2
    assert "--port" in capsys.readouterr().err


def test_open_log_errors_are_the_clis(tmp_path):
    with pytest.raises(FileNotFoundError):
        S.open_log(str(tmp_path / "nothing.csv"))
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError):
        S.open_log(str(bad))


def test_saved_report_is_fits_report(opened, tmp_path):
    res = S.calibrate(opened, {"payload": None})
    p = S.save_report(opened, res, str(tmp_path / "rep"))
    html = (p / "report.html").read_text()
    assert "payload" in html and (p / "report.md").exists()
    with pytest.raises(FileExistsError, match="choose a new name"):
        S.save_report(opened, res, str(p))


def test_page_without_gl_says_why_and_the_rest_works(opened):
    """Where no OpenGL context can be made, the arm view says why; the figures and the refit still work."""
    from bokeh.document import Document

    from franka_vs_gym.validation.app.arm import ArmView
    from franka_vs_gym.validation.app.page import Page
    from franka_vs_gym.validation.app.state import App

    app = App()
    app.arm = ArmView()
    app.arm.error = "the arm view needs offscreen OpenGL (MUJOCO_GL=none) and this machine has none: test"
    app.opened, app.log_version, app.version = opened, 1, 1
    page = Page(app, Document())
    page._draw_arm()
    assert "no arm view" in page.arm_div.text and "MUJOCO_GL" in page.arm_div.text
    page.toggles["payload"].active = [0]
    assert page.current.enabled == {"payload": None}
    assert len(page.src.data["cur"]) > 1000
    import re

    m = re.search(r"data-total='([0-9.]+)' data-baseline='([0-9.]+)'", page.rmse_div.text)
    assert float(m.group(1)) < 0.5 * float(m.group(2))


def test_page_without_a_log_waits_for_one():
    from bokeh.document import Document

    from franka_vs_gym.validation.app.page import Page
    from franka_vs_gym.validation.app.state import App

    page = Page(App(), Document())
    assert "no log opened yet" in page.status.text
    assert all(g.disabled for g in page.toggles.values()) and page.current is None


def test_intervals_of_the_enabled_set_cover_the_hidden_payload(opened, payload_log):
    ci = S.intervals(opened, {"payload": None})
    lo, hi = ci["payload"]["mass_kg"]
    assert lo < hi and abs(0.5 * (lo + hi) - payload_log[1]["params"]["mass_kg"]) < 0.05
    assert S.intervals(opened, {}) == {}


def test_arm_links_take_the_colour_of_their_joints_residual():
    """The arm view colours link j+1 by joint j's residual: a large residual on joint 3 makes red pixels that a
    residual within the noise does not; the PNG sent to the page is the image, losslessly."""
    import base64

    import cv2

    from franka_vs_gym.validation.app.arm import ArmView, NoGL

    a = ArmView()
    q = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
    try:
        calm = a.image(q, np.zeros(7))
    except NoGL as e:
        pytest.skip(f"no offscreen OpenGL here: {e}")
    hot = a.image(q, np.array([0, 0, 0, 10.0, 0, 0, 0]))

    def red(img):
        r, g, b = (img[..., i].astype(int) for i in range(3))
        return int(np.sum((r > 180) & (g < 90) & (b < 90)))

    assert red(hot) > 200 and red(calm) < 20, (red(hot), red(calm))
    url = a.png_data_url(q, np.array([0, 0, 0, 10.0, 0, 0, 0]))
    png = np.frombuffer(base64.b64decode(url.split(",", 1)[1]), np.uint8)
    np.testing.assert_array_equal(cv2.imdecode(png, cv2.IMREAD_COLOR)[:, :, ::-1], hot)
