"""Which robot a log is compared with: the one it declares (``franka-vs serve --robot fr3 --record`` writes it into
the sidecar), else the FER with a hint when the positions only fit another robot's joint range."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.validation.loading import load_log
from franka_vs_gym.validation.logs import MeasurementLog, save_log


def _fr3_log(**kw) -> MeasurementLog:
    """The FR3 (no tool) on a slow multi-sine about a pose whose sixth joint is at 4.1 rad (inside the FR3's
    [0.54, 4.52] rad, beyond the FER's 3.75 rad), torque from the FR3 model's inverse dynamics plus 0.02 Nm noise."""
    rng = np.random.default_rng(0)
    rate, duration = 250.0, 12.0
    t = np.arange(0.0, duration, 1.0 / rate)
    f = rng.uniform(0.1, 0.4, (7, 3))
    a = rng.uniform(0.05, 0.12, (7, 3)) / (2 * np.pi * f)
    ph = rng.uniform(0, 2 * np.pi, (7, 3))
    arg = 2 * np.pi * f[None] * t[:, None, None] + ph[None]
    q = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 4.1, 0.7])[None] + (a[None] * np.sin(arg)).sum(axis=2)
    dq = (a[None] * 2 * np.pi * f[None] * np.cos(arg)).sum(axis=2)
    ddq = -(a[None] * (2 * np.pi * f[None]) ** 2 * np.sin(arg)).sum(axis=2)
    fm = FrankaModel(robot="fr3", tool=None)
    d = fm.model.createData()
    tau = np.array([pin.rnea(fm.model, d, q[k], dq[k], ddq[k]) for k in range(len(t))])
    tau = tau + rng.normal(0, 0.02, tau.shape)
    return MeasurementLog(t, q, dq, tau, tool="none", **kw)


def test_a_log_that_declares_the_fr3_is_compared_with_the_fr3(tmp_path):
    from franka_vs_gym.validation.compare import compare
    from franka_vs_gym.validation.diagnose import diagnose

    p = save_log(_fr3_log(extra={"source": "franka-vs serve", "robot": "fr3"}), tmp_path / "fr3.npz")
    log = load_log(p)  # the sidecar's "robot" survives the round trip
    d = diagnose(log)
    a = d.assumptions
    assert a["robot"] == "fr3" and a["robot_source"] == "declared by the log", a
    assert np.sqrt(np.mean(d.rmse_tau ** 2)) < 0.05, d.rmse_tau  # the FR3's own dynamics: the noise is left
    fer = diagnose(log, robot="fer")  # --robot overrides the log; the FER's dynamics are off by much more
    assert fer.assumptions["robot_source"] == "--robot"
    assert np.sqrt(np.mean(fer.rmse_tau ** 2)) > 5 * np.sqrt(np.mean(d.rmse_tau ** 2))
    with pytest.raises(ValueError, match=r"robot 'fer'.*recorded on the fr3"):
        compare(log, ModelConfig(robot="fer"), do_replay=False)


def test_an_undeclared_log_beyond_the_fers_range_gets_a_hint():
    from franka_vs_gym.validation.diagnose import diagnose

    d = diagnose(_fr3_log(), select=False)
    src = d.assumptions["robot_source"]
    assert d.assumptions["robot"] == "fer" and src.startswith("not declared by the log: the FER assumed"), src
    assert "within the FR3's" in src and "--robot fr3" in src, src
