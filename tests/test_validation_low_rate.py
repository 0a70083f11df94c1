"""Low-rate logs (a 30 Hz ROS recording): the acceleration's derivative is exact in the band, the noise the
measured velocity puts into it is estimated, and the armature's interval holds the errors-in-variables bias that
noise causes (franka_vs_gym.validation.signals, franka_vs_gym.validation.uncertainty.inertial_bias)."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.description import FER
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.validation.logs import MeasurementLog
from franka_vs_gym.validation.signals import CleanSettings, clean, derivative


def test_spline_derivative_is_exact_in_band_where_the_central_difference_is_not():
    rate, f = 30.0, 2.0
    t = np.arange(300) / rate
    x = np.sin(2 * np.pi * f * t)
    exact = 2 * np.pi * f * np.cos(2 * np.pi * f * t)
    mid = slice(20, -20)
    err = np.abs(derivative(x, rate, "spline") - exact)[mid].max() / (2 * np.pi * f)
    assert err < 1e-3  # the spline's gain 3 sin w / (w (2 + cos w)) = 0.9997
    w = 2 * np.pi * f / rate
    central = derivative(x, rate, "central")[mid]
    gain = np.abs(central).max() / (2 * np.pi * f)
    assert gain == pytest.approx(np.sin(w) / w, abs=2e-3)  # 0.971: 3 % of M(q) ddq left in the residual
    with pytest.raises(ValueError, match="derivative must be one of"):
        CleanSettings(derivative="five_point")


def test_auto_derivative_is_the_central_difference_only_where_it_is_exact():
    assert CleanSettings().resolved(1e-3).derivative == "central"  # 1 kHz, 10 Hz cutoff: gain 0.99934
    assert CleanSettings().resolved(1e-2).derivative == "spline"  # 100 Hz: 0.935 at the cutoff
    assert CleanSettings().resolved(1 / 30).derivative == "spline"


def _slow_log(rate: float, dq_noise: float, seed: int = 0, duration: float = 12.0, armature=None):
    """The FER (with hand, the default model) on a slow multi-sine, torque from the model's inverse dynamics plus an
    armature, sampled at ``rate``: q exact, dq with white noise of ``dq_noise`` rad/s, torque with 0.01 Nm."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1.0 / rate)
    f = rng.uniform(0.1, 0.4, (7, 3))
    a = rng.uniform(0.1, 0.25, (7, 3)) / (2 * np.pi * f)
    ph = rng.uniform(0, 2 * np.pi, (7, 3))
    arg = 2 * np.pi * f[None] * t[:, None, None] + ph[None]
    q = np.asarray(FER.neutral())[None] + (a[None] * np.sin(arg)).sum(axis=2)
    dq = (a[None] * 2 * np.pi * f[None] * np.cos(arg)).sum(axis=2)
    ddq = -(a[None] * (2 * np.pi * f[None]) ** 2 * np.sin(arg)).sum(axis=2)
    fm = FrankaModel(ModelConfig())
    d = fm.model.createData()
    tau = np.array([pin.rnea(fm.model, d, q[k], dq[k], ddq[k]) for k in range(len(t))]) + fm.friction(dq)
    if armature is not None:
        tau = tau + armature * ddq
    tau = tau + rng.normal(0, 0.01, tau.shape)
    dq_meas = dq + rng.normal(0, dq_noise, dq.shape) if dq_noise else dq
    return MeasurementLog(t, q, dq_meas, tau, tool="franka_hand")


def test_assumptions_name_the_derivative_the_log_was_differentiated_with():
    """The diagnosis' assumptions say how ddq was taken: the central difference at 1 kHz, the spline's derivative at
    30 Hz (they had said "central difference" at every rate)."""
    from franka_vs_gym.validation.diagnose import diagnose

    for rate, said in ((1000.0, "central difference"), (30.0, "cubic spline")):
        d = diagnose(_slow_log(rate, 0.0), select=False)
        assert said in d.assumptions["cleaning"]["acceleration"], (rate, d.assumptions["cleaning"])


def test_ddq_noise_estimate_matches_the_noise_the_velocity_puts_into_ddq():
    noisy = clean(_slow_log(30.0, 0.003))
    exact = clean(_slow_log(30.0, 0.0))
    measured = np.std(noisy.ddq - exact.ddq, axis=0)
    assert np.all(noisy.ddq_noise == pytest.approx(measured, rel=0.25))
    assert np.all(exact.ddq_noise < 0.05 * measured)


def test_armature_interval_holds_the_bias_the_velocity_noise_causes():
    from franka_vs_gym.validation.compare import baseline_config
    from franka_vs_gym.validation.effects import Context, get_effect
    from franka_vs_gym.validation.selection import Engine, Term
    from franka_vs_gym.validation.uncertainty import confidence

    truth = np.array([0.2, 0.2, 0.15, 0.15, 0.05, 0.05, 0.02])
    data = clean(_slow_log(30.0, 0.006, seed=1, armature=truth))
    ctx = Context(data, baseline_config(data.log, None, False))
    e = get_effect("armature")
    sf = Engine(ctx, ctx.residual, [np.arange(ctx.n)]).fit([Term(e, e.shape(ctx, ctx.residual), list(range(7)))],
                                                           cv=False)
    fitted = np.asarray(e.public(sf.fits[0])["armature_kgm2"])
    conf = confidence(ctx, [e], sf.fits, ctx.residual, draws=50)
    ratio = fitted / truth
    corrected = (fitted - conf.bias) / truth
    # errors in variables: the noisy acceleration pulls the armature down (through M(q) ddq in the residual)
    assert np.median(ratio) < 0.85
    # the first-order bias explains it: the corrected number is within 10 % of the truth on the moving joints
    assert np.median(np.abs(corrected - 1)) < 0.1
    assert np.all(conf.bias <= 0)
    ci = np.array(conf.params_ci95[0]["armature_kgm2"])
    inside = (ci[:, 0] <= truth) & (truth <= ci[:, 1])
    assert inside.sum() >= 6
