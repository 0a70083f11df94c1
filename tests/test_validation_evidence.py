"""diagnose's default evidence (``evidence="band"``, method step 2): a gravity tilt is named by its horizontal part
only. Checked against physics on a simulated log whose measured torque gets an exact gravity change computed from
the model on the log's own poses: a change of |g| alone (a scale of every body's first mass moment, i.e. a mass
error) is not named a tilt, a rotation of gravity by the same order is, with its angle."""

from __future__ import annotations

import math

import numpy as np
import pytest

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.validation.diagnose import diagnose
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.logs import MeasurementLog


@pytest.fixture(scope="module")
def clean_log():
    log, _ = make_hidden_effect_log("none", 31, duration=10.0)
    return log


def _with_gravity(log: MeasurementLog, g: np.ndarray) -> MeasurementLog:
    """``log`` whose measured torque is that of a world with gravity ``g`` (the model's gravity torque difference
    on the log's poses added)."""
    base, changed = FrankaModel(ModelConfig()), FrankaModel(ModelConfig(gravity=g))
    d = np.array([changed.gravity(q) - base.gravity(q) for q in log.q])
    return MeasurementLog(log.time, log.q, log.dq, log.tau_J + d, tool=log.tool, gravity=log.gravity,
                          controller=log.controller, extra=dict(log.extra), source=log.source,
                          tool_declared=log.tool_declared, tau_J_d=log.tau_J_d)


def _tilt(d):
    return next((s for s in d.selection if s.effect == "gravity_tilt"), None)


def test_default_evidence_is_the_motion_band_with_the_horizontal_tilt_rule(clean_log):
    d = diagnose(clean_log)
    assert "horizontal part" in d.assumptions["evidence"]
    assert d.selected == [], d.selected


def test_a_change_of_g_magnitude_is_not_named_a_tilt_a_rotation_is(clean_log):
    g0 = np.asarray(ModelConfig().gravity, dtype=float)
    # |g| 1.5 % larger (five times Earth's whole range of normal gravity), direction unchanged
    scaled = _with_gravity(clean_log, 1.015 * g0)
    d_full = diagnose(scaled, evidence="full")
    d = diagnose(scaled)
    # counting every sample, the three-parameter law takes the magnitude change as a "tilt" of 0 degrees
    t_full = _tilt(d_full)
    assert t_full is not None and t_full.params["tilt_deg"] < 0.05, d_full.selected
    assert _tilt(d) is None, [(s.effect, s.params) for s in d.selection]
    # the ranking says why, with the change of |g| the law found (+0.147 m/s^2)
    (why,) = [p for c in d.ranking if c.effect == "gravity_tilt" for p in c.problems]
    assert "not a tilt" in why and "+1.50 %" in why, why
    # a 1 degree rotation about the base x axis: named, with its angle
    a = math.radians(1.0)
    rot = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]) @ g0
    d_rot = diagnose(_with_gravity(clean_log, rot))
    t = _tilt(d_rot)
    assert t is not None, d_rot.selected
    assert t.params["tilt_deg"] == pytest.approx(1.0, rel=0.1)


def test_a_long_delay_is_the_exact_shift_and_brings_nothing_beside_it(clean_log):
    """A 60 ms lag of the measured torque (the model's torque on the log's own motion, shifted): the delay law is
    first order in the lag; its remainder at 60 ms is systematic, and the default names the delay alone, with the
    lag, from the exact shift."""
    from franka_vs_gym.validation.evaluate import shift
    from franka_vs_gym.validation.injected import _torque, motion

    m = motion(clean_log)
    tau = _torque(ModelConfig(), m)
    lagged = shift(tau, m.time, 0.060)
    first = tau - 0.060 * np.gradient(tau, m.time, axis=0)
    # the first-order law leaves a remainder well above a hundredth of the lag's own size
    rem = np.sqrt(np.mean((lagged - first)[500:-500] ** 2))
    assert rem > 0.03 * np.sqrt(np.mean((lagged - tau)[500:-500] ** 2))
    log = MeasurementLog(clean_log.time, clean_log.q, clean_log.dq, clean_log.tau_J + lagged - tau,
                         tool=clean_log.tool, gravity=clean_log.gravity, controller=clean_log.controller,
                         extra=dict(clean_log.extra), source=clean_log.source, tool_declared=clean_log.tool_declared)
    d = diagnose(log)
    assert d.selected == ["delay"], [(s.effect, s.joints) for s in d.selection]
    assert d.selection[0].params["delay_s"] == pytest.approx(0.060, rel=0.03)
