"""Measurement-log formats: round trips, the Gaz folder, and clear errors on malformed files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from franka_vs_gym.validation.loading import load_log
from franka_vs_gym.validation.logs import MeasurementLog, save_log, sidecar_path

GAZ = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "gaz2019_traj1"


def _log(n: int = 200, **kw) -> MeasurementLog:
    rng = np.random.default_rng(0)
    t = np.arange(n) * 1e-3
    q = 0.3 * np.sin(np.outer(t, np.arange(1, 8))) + np.array([0, -0.7, 0, -2.3, 0, 1.5, 0.7])
    return MeasurementLog(t, q, rng.normal(0, 0.2, (n, 7)), rng.normal(0, 5, (n, 7)), **kw)


@pytest.mark.parametrize("ext", [".csv", ".npz"])
def test_round_trip_with_sidecar(tmp_path, ext):
    log = _log(tau_J_d=np.ones((200, 7)), tool=None, controller={"law": "eq2", "kp": [400.0] * 7},
               gravity=[0.0, 1.0, -9.76])
    p = save_log(log, tmp_path / f"run{ext}")
    back = load_log(p)
    for f in ("time", "q", "dq", "tau_J", "tau_J_d"):
        np.testing.assert_allclose(getattr(back, f), getattr(log, f), rtol=1e-9, atol=1e-12)
    assert back.q_d is None and back.tool is None
    assert back.controller == {"law": "eq2", "kp": [400.0] * 7}
    np.testing.assert_allclose(back.gravity, [0.0, 1.0, -9.76])
    assert json.loads(sidecar_path(p).read_text())["tool"] is None


def test_save_refuses_overwrite(tmp_path):
    p = save_log(_log(), tmp_path / "a.csv")
    before = p.read_bytes()
    with pytest.raises(FileExistsError):
        save_log(_log(50), p)
    assert p.read_bytes() == before
    save_log(_log(50), p, overwrite=True)
    assert load_log(p).n == 50


def test_underscore_columns_and_default_tool(tmp_path):
    log = _log()
    cols = ["time"] + [f"{f}_{i}" for f in ("q", "dq", "tau_J") for i in range(7)]
    data = np.column_stack([log.time, log.q, log.dq, log.tau_J])
    p = tmp_path / "u.csv"
    p.write_text(",".join(cols) + "\n" + "\n".join(",".join(repr(float(x)) for x in row) for row in data))
    back = load_log(p)
    np.testing.assert_allclose(back.q, log.q)
    assert back.tool == "franka_hand"  # nothing declared: the library default


def _write_csv(path: Path, cols, data) -> Path:
    path.write_text(",".join(cols) + "\n" + "\n".join(",".join(repr(float(x)) for x in r) for r in data) + "\n")
    return path


def _cols(nj=7, fields=("q", "dq", "tau_J")):
    return ["time"] + [f"{f}[{i}]" for f in fields for i in range(nj)]


def test_malformed_files_name_the_problem(tmp_path):
    log = _log(50)
    good = np.column_stack([log.time, log.q, log.dq, log.tau_J])
    # missing column group
    p = _write_csv(tmp_path / "m1.csv", _cols(fields=("q", "dq")), good[:, :15])
    with pytest.raises(ValueError, match=r"tau_J"):
        load_log(p)
    # wrong joint count (6 joints)
    data6 = np.column_stack([log.time, log.q[:, :6], log.dq[:, :6], log.tau_J[:, :6]])
    p = _write_csv(tmp_path / "m2.csv", _cols(nj=6), data6)
    with pytest.raises(ValueError, match=r"7 joints"):
        load_log(p)
    # NaN
    bad = good.copy()
    bad[10, 3] = np.nan
    p = _write_csv(tmp_path / "m3.csv", _cols(), bad)
    with pytest.raises(ValueError, match=r"q\[2\] contains NaN.*row 10"):
        load_log(p)
    # decreasing time
    bad = good.copy()
    bad[20, 0] = bad[5, 0]
    p = _write_csv(tmp_path / "m4.csv", _cols(), bad)
    before = p.read_bytes()
    with pytest.raises(ValueError, match=r"not monotonic"):
        load_log(p)
    assert p.read_bytes() == before  # never modified
    # degrees
    bad = good.copy()
    bad[:, 1:8] = np.degrees(bad[:, 1:8])
    p = _write_csv(tmp_path / "m5.csv", _cols(), bad)
    with pytest.raises(ValueError, match=r"rad.*degrees"):
        load_log(p)
    # milliseconds
    bad = good.copy()
    bad[:, 0] *= 1000
    p = _write_csv(tmp_path / "m6.csv", _cols(), bad)
    with pytest.raises(ValueError, match=r"milliseconds"):
        load_log(p)
    # a slow recording (a ROS topic at 10 Hz) is seconds, not milliseconds: read, at its own time
    slow = good.copy()
    slow[:, 0] *= 100
    back = load_log(_write_csv(tmp_path / "m6b.csv", _cols(), slow))
    np.testing.assert_allclose(back.time, slow[:, 0])
    # text in a number field
    p = tmp_path / "m7.csv"
    p.write_text(",".join(_cols()) + "\n" + ",".join(["0.0"] + ["abc"] + ["1"] * 20) + "\n")
    with pytest.raises(ValueError, match=r"line 2.*'abc'"):
        load_log(p)
    with pytest.raises(FileNotFoundError):
        load_log(tmp_path / "absent.csv")


@pytest.mark.skipif(not GAZ.is_dir(), reason="Gaz et al. 2019 data not available")
def test_gaz_folder_loads():
    log = load_log(GAZ)
    assert log.n == 20544 and log.tool is None
    np.testing.assert_allclose(log.q[0], np.loadtxt(GAZ / "gen_q0.txt"), atol=1e-3)
    assert 20.9 < log.duration < 21.1


def test_cleaning_messy_log_recovers_the_signals():
    """Irregular timestamps, stale repeated rows and noise: the cleaned signals match the analytic truth."""
    from franka_vs_gym.validation.signals import CleanSettings, clean, highpass_power_fraction

    rng = np.random.default_rng(1)
    dt = rng.choice([0.0007, 0.001, 0.001, 0.001, 0.0013], size=12000)
    t = np.concatenate([[0.0], np.cumsum(dt)])
    w = np.array([0.6, 0.9, 1.3, 1.7, 2.2, 2.9, 3.5])  # rad/s
    q = 0.4 * np.sin(np.outer(t, w)) + np.array([0, -0.7, 0, -2.3, 0, 1.5, 0.7])
    dq = 0.4 * w * np.cos(np.outer(t, w)) + rng.normal(0, 1e-3, (len(t), 7))
    sigma = np.array([0.3, 0.3, 0.2, 0.2, 0.1, 0.1, 0.05])
    tau_true = 5 * np.sin(np.outer(t, w))
    tau = tau_true + rng.normal(size=tau_true.shape) * sigma
    stale = rng.choice(np.arange(1, len(t)), size=300, replace=False)
    for k in np.sort(stale):  # the robot did not refresh these samples: the previous values are repeated
        q[k], dq[k], tau[k] = q[k - 1], dq[k - 1], tau[k - 1]
    log = MeasurementLog(t, q, dq, tau, tool=None)
    before = log.q.copy()
    data = clean(log, CleanSettings())
    np.testing.assert_array_equal(log.q, before)  # the input is not modified
    assert data.report.stale_rows == 300
    assert np.allclose(np.diff(data.time), 1e-3)
    tt = data.time + t[0]
    np.testing.assert_allclose(data.q, 0.4 * np.sin(np.outer(tt, w)) + before[0] - 0.4 * np.sin(0 * w), atol=2e-4)
    ddq_true = -0.4 * w ** 2 * np.sin(np.outer(tt, w))
    assert np.abs(data.ddq - ddq_true).max() < 0.02
    # the floor is the noise of the resampled torque (interpolating irregular samples averages neighbours):
    # compare with the injected noise passed through the same resampling
    keep = np.ones(len(t), dtype=bool)
    keep[stale] = False
    noise = (tau - tau_true)[keep]
    resampled = np.column_stack([np.interp(tt, t[keep], noise[:, j]) for j in range(7)])
    np.testing.assert_allclose(data.noise, resampled.std(axis=0), rtol=0.05)
    assert np.all(data.noise < sigma) and np.all(data.noise > 0.7 * sigma)
    assert 0.9 < highpass_power_fraction(CleanSettings()) < 1.0


def test_cleaning_rejects_long_gaps_and_short_logs():
    from franka_vs_gym.validation.signals import clean

    log = _log(2000)
    t = log.time.copy()
    t[1000:] += 0.2
    with pytest.raises(ValueError, match=r"gap"):
        clean(MeasurementLog(t, log.q, log.dq, log.tau_J))
    with pytest.raises(ValueError, match=r"too short"):
        clean(_log(100))
