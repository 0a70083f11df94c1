"""The evidence criterion (franka_vs_gym.validation.criterion): its closed form against the Gaussian marginal
likelihood computed directly, its priors against the physical ranges, and its selection on simulated logs."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import franka_vs_gym.validation.diagnose  # noqa: F401
from franka_vs_gym.validation.candidates import resolve_effects
from franka_vs_gym.validation.compare import as_processed, baseline_config
from franka_vs_gym.validation.criterion import LOG_RATIO, EvidenceSelector, Library, prior_cov
from franka_vs_gym.validation.effects import Context, get_effect
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.selection import Engine, contiguous_folds

dg = sys.modules["franka_vs_gym.validation.diagnose"]


def _library(effect: str, seed: int, magnitude: float = 1.0, duration: float = 6.0):
    log, answer = make_hidden_effect_log(effect, seed, duration=duration, magnitude=magnitude)
    data = as_processed(log, None)
    cfg = baseline_config(data.log, None, False, data=data)
    ctx = Context(data, cfg)
    eng = Engine(ctx, ctx.residual, contiguous_folds(ctx.n, 5), band=True)
    effects = [e for e in resolve_effects(None) if e.name != "link_inertials"]
    return Library(ctx, eng, effects), answer


def test_evidence_is_the_gaussian_marginal_likelihood():
    """ln Z(S1) - ln Z(S2) from the closed form equals the difference of ln N(y; 0, I + X S X^T) computed directly
    (the whitened band, each set's columns and prior covariance)."""
    lib, _ = _library("viscous_friction", 3)
    X, Y = lib.X, lib.Y

    def direct(members):
        idx = sorted(members)
        if not idx:
            C = np.eye(len(Y))
        else:
            cols = np.concatenate([np.arange(lib.units[i].cols.start, lib.units[i].cols.stop) for i in idx])
            S = np.zeros((len(cols), len(cols)))
            pos = 0
            for i in idx:
                p = lib.units[i].cols.stop - lib.units[i].cols.start
                S[pos:pos + p, pos:pos + p] = lib.prior[i]
                pos += p
            Xs = X[:, cols]
            C = np.eye(len(Y)) + Xs @ S @ Xs.T
        sign, logdet = np.linalg.slogdet(C)
        return -0.5 * float(Y @ np.linalg.solve(C, Y)) - 0.5 * logdet

    names = [(u.name, u.joint) for u in lib.units]
    a = frozenset({names.index(("viscous_friction", 2))})
    b = frozenset({names.index(("viscous_friction", 2)), names.index(("gravity_tilt", None)),
                   names.index(("asymmetric_friction", 4))})
    for s1, s2 in ((a, frozenset()), (b, a), (b, frozenset())):
        want = direct(s1) - direct(s2)
        got = lib.log_evidence(s1) - lib.log_evidence(s2)
        assert got == pytest.approx(want, rel=1e-6, abs=1e-6)


def test_priors_span_the_physical_ranges():
    """+-2 prior standard deviations are the effects' plausible ranges: the tilt's horizontal part 30 deg of g,
    its magnitude Earth's 0.03 m/s^2; a payload's mass 3.5 kg; viscous friction 0.2 tau_max."""
    lib, _ = _library("none", 1, duration=3.0)
    ctx = lib.ctx
    S = prior_cov(get_effect("gravity_tilt"), ctx, 3, None)
    u = np.asarray(ctx.config.gravity, dtype=float)
    u = u / np.linalg.norm(u)
    assert 2 * np.sqrt(u @ S @ u) == pytest.approx(0.03)
    h = np.cross(u, [1.0, 0.0, 0.0])
    h /= np.linalg.norm(h)
    assert 2 * np.sqrt(h @ S @ h) == pytest.approx(9.81 * 0.5, rel=1e-3)
    assert 2 * np.sqrt(prior_cov(get_effect("payload"), ctx, 10, None)[0, 0]) == pytest.approx(3.5)
    tau = ctx.config.robot.limit_arrays()["tau_max"]
    assert 2 * np.sqrt(prior_cov(get_effect("viscous_friction"), ctx, 1, 5)[0, 0]) == pytest.approx(0.2 * tau[5])


@pytest.mark.parametrize("effect,seed,magnitude", [("gravity_tilt", 41, 1.5), ("viscous_friction", 3, 1.0),
                                                   ("payload", 7, 1.0)])
def test_selection_names_a_hidden_effect(monkeypatch, effect, seed, magnitude):
    """On a simulated log with one hidden effect the criterion's selection names it (and nothing on the joints a
    per-joint law does not touch)."""
    log, answer = make_hidden_effect_log(effect, seed, duration=8.0, magnitude=magnitude)
    monkeypatch.setattr(dg, "_Selector", lambda ctx, eng, noise, effects, verbose, many_test=False:
                        EvidenceSelector(ctx, eng, noise, effects, verbose))
    d = dg.diagnose(log)
    assert effect in d.selected, (d.selected, answer)
    s = next(s for s in d.selection if s.effect == effect)
    assert s.score > LOG_RATIO
