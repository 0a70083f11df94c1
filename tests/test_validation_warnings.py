"""No Python warnings reach a user of the workbench: ``diagnose`` and ``fit --add auto`` on clean, noise-free logs run
under ``warnings.simplefilter("error")`` (any RuntimeWarning, e.g. an overflow in the held-out fits or a log of
zero, fails them), and the held-out fit of a parameter that only the held-out block excites stays finite."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from franka_vs_gym.model import FrankaModel
from franka_vs_gym.model.config import ModelConfig, Tool
from franka_vs_gym.model.description import FER
from franka_vs_gym.validation.effects import Effect
from franka_vs_gym.validation.logs import MeasurementLog
from franka_vs_gym.validation.selection import Engine, Term


def _exact_log(seconds: float = 4.0, still: tuple[int, ...] = ()) -> MeasurementLog:
    """A smooth 1 kHz motion (joints ``still`` held exactly still) with the exact inverse-dynamics torques of the
    FER with the Franka Hand, no noise."""
    m = FrankaModel(ModelConfig(tool=Tool.franka_hand()))
    t = np.arange(int(seconds * 1000)) * 1e-3
    w = 2 * np.pi * np.array([0.3, 0.4, 0.5, 0.35, 0.6, 0.45, 0.7])
    w[list(still)] = 0.0
    q = np.array(FER.q_neutral) + 0.3 * np.sin(np.outer(t, w))
    dq = 0.3 * w * np.cos(np.outer(t, w))
    ddq = -0.3 * w ** 2 * np.sin(np.outer(t, w))
    tau = np.array([m.inverse_dynamics(q[k], dq[k], ddq[k]) for k in range(len(t))])
    return MeasurementLog(t, q, dq, tau, tool="franka_hand")


@pytest.mark.parametrize("still", [(), (1, 3, 5)])
def test_diagnose_and_fit_on_a_noise_free_log_raise_no_warning(still):
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.fitting import fit_effects

    log = _exact_log(4.0, still)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = diagnose(log)
        f = fit_effects(log, ["auto"])
    # the exact model: nothing to name, and the fit leaves the model's error where it was (about 1e-3 Nm, the
    # processing's own error, far below the 0.01 Nm floor used)
    assert d.verdict == "none" and d.selected == [] and d.explained
    assert np.all(np.isfinite(d.rmse_tau_selected)) and np.all(f.rmse_after < 0.01)


def test_a_noise_free_simulated_effect_is_named_without_warnings():
    """A payload hidden in a noise-free simulated log (the plant's own torque, no measurement noise): named, with
    its mass within 10 % of the generator's, and no warning on the way."""
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    log, answer = make_hidden_effect_log("payload", 0, duration=6.0, noise_scale=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = diagnose(log)
    assert d.verdict == "payload"
    mass = next(s.params["mass_kg"] for s in d.selection if s.effect == "payload")
    assert mass == pytest.approx(answer["params"]["mass_kg"], rel=0.1)


class _Burst(Effect):
    """A test effect: one column per joint that is non-zero only in the last 15 % of the log (tiny elsewhere)."""

    name = "burst_for_test"

    def design(self, ctx, shape):
        n = ctx.n
        col = np.full(n, 1e-160)
        col[int(0.85 * n):] = 1.0
        return np.repeat(col[:, None, None], 7, axis=1)


def test_held_out_fit_of_a_parameter_seen_in_one_block_is_finite():
    """Fitted on the four blocks that do not excite it, the burst's coefficient is not estimated (0, not a value
    scaled up from a rounding-level column), so the held-out error of that block is the target's own; in sample the
    coefficient is the least-squares one (the burst's mean target on its samples)."""
    n = 5000
    rng = np.random.default_rng(0)
    y = rng.normal(size=(n, 7))
    y[int(0.85 * n):] += 2.0
    ctx = SimpleNamespace(n=n, data=SimpleNamespace(settings=SimpleNamespace(rate=1000.0, cutoff=10.0, order=4)))
    edges = np.linspace(0, n, 6).astype(int)
    folds = [np.arange(edges[i], edges[i + 1]) for i in range(5)]
    eng = Engine(ctx, y, folds)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sf = eng.fit([Term(_Burst(), {}, list(range(7)))])
    last = folds[-1]
    burst = np.arange(int(0.85 * n), n)
    assert np.all(np.isfinite(sf.mse_cv))
    # the held-out MSE: the four blocks without the burst predicted by the fit on the others (which include it:
    # coefficient ~2 times 1e-160 there, nothing), the last block by a coefficient of 0
    expect = (sum(np.sum(y[b] ** 2, axis=0) for b in folds[:-1]) + np.sum(y[last] ** 2, axis=0)) / n
    np.testing.assert_allclose(sf.mse_cv, expect, rtol=1e-9)
    np.testing.assert_allclose(sf.coefs[0][:, 0], y[burst].mean(axis=0), rtol=1e-7)
