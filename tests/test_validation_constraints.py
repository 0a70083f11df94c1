"""Physical constraints inside the fit (issue 34, section 4): what ``franka-vs fit`` fits is physically valid by
construction (a consistent body, a dissipative friction law, a delay in its box), equal to the least-squares answer
where that is valid, and the constrained optimum of the same misfit where it is not. The gravity tilt is not
constrained (a free vector beside the constrained members)."""

from __future__ import annotations

import importlib

import numpy as np
import pinocchio as pin
import pytest

from franka_vs_gym.validation.compare import as_processed, baseline_config
from franka_vs_gym.validation.effects import Context, get_effect
from franka_vs_gym.validation.effects.base import MAX_DELAY, MIN_DELAY
from franka_vs_gym.validation.effects.inertial import _payload_body
from franka_vs_gym.validation.evaluate import FLANGE_OFFSET
from franka_vs_gym.validation.hidden import make_hidden_effect_log
from franka_vs_gym.validation.signals import decimated

_fitting = importlib.import_module("franka_vs_gym.validation.fitting")


@pytest.fixture(scope="module")
def ctx() -> Context:
    log, _ = make_hidden_effect_log("none", seed=0, duration=6.0)
    data = as_processed(log)
    return Context(decimated(data), baseline_config(data.log, None, False, data=data))


def _fit(ctx, names, y):
    """The fit path's joint fit (what ``franka-vs fit`` fits on all samples)."""
    return _fitting.fit_jointly(ctx, [(get_effect(n), None) for n in names], y, np.arange(ctx.n), refine=True)


def _pseudo_eigs(pi: np.ndarray) -> np.ndarray:
    """Eigenvalues of a body's pseudo-inertia, from pinocchio's own inertia (independent of the project's)."""
    body = pin.Inertia.FromDynamicParameters(np.asarray(pi, dtype=float))
    return np.linalg.eigvalsh(body.toPseudoInertia().toMatrix())


def _pseudo_by_hand(m: float, c: np.ndarray, inertia_c: np.ndarray) -> np.ndarray:
    """Pseudo-inertia [[Sigma, h], [h^T, m]] from a mass, centre of mass and inertia about it (Wensing et al. 2018):
    Sigma = tr(I_o)/2 - I_o with I_o = I_c + m (|c|^2 1 - c c^T), h = m c."""
    io = inertia_c + m * (c @ c * np.eye(3) - np.outer(c, c))
    J = np.zeros((4, 4))
    J[:3, :3] = 0.5 * np.trace(io) * np.eye(3) - io
    J[:3, 3] = J[3, :3] = m * c
    J[3, 3] = m
    return J


def _misfit(ctx, e, fit, y) -> float:
    return float(np.sum((y - e.contribution(ctx, fit)) ** 2))


def test_a_non_physical_payload_is_fitted_as_the_closest_consistent_body(ctx):
    pay = get_effect("payload")
    good = pin.Inertia(0.8, np.array([0.01, -0.02, 0.15]), np.diag([2e-3, 2.5e-3, 1.5e-3])).toDynamicParameters()
    bad = good.copy()
    bad[[4, 6, 9]] -= 0.05  # moments about the joint-7 origin far below what the mass and its lever allow
    assert _pseudo_eigs(bad).min() < 0  # the injected torque's least-squares answer is not a body
    y = ctx.ev.Y_last @ bad
    ls = pay.fit(ctx, y, np.arange(ctx.n))
    np.testing.assert_allclose(pay.coef(ls), bad, atol=1e-6 * np.abs(bad).max())
    (f,) = _fit(ctx, ["payload"], y)
    th = pay.coef(f)
    # positive semi-definite (the optimum lies on the boundary of the consistent set: round-off there), by
    # pinocchio's pseudo-inertia and by hand from mass, centre of mass and inertia
    w = _pseudo_eigs(th)
    assert w.min() > -1e-12 * w.max(), w
    body = pin.Inertia.FromDynamicParameters(th)
    w2 = np.linalg.eigvalsh(_pseudo_by_hand(body.mass, np.asarray(body.lever), body.inertia))
    assert w2.min() > -1e-12 * w2.max(), w2
    assert 0 < body.mass <= 3.5
    new = pay.apply(ctx.config, f)  # the model takes it (the simulator's own checks included)
    assert new.payload.mass == pytest.approx(body.mass)
    # the constrained optimum: no worse than the least-squares body projected afterwards (what apply did before)
    body_pr, _ = _payload_body(bad)
    proj = pin.Inertia(body_pr.mass, np.asarray(body_pr.com) + FLANGE_OFFSET, body_pr.inertia).toDynamicParameters()
    assert _misfit(ctx, pay, f, y) <= float(np.sum((y - ctx.ev.Y_last @ proj) ** 2))
    assert _misfit(ctx, pay, f, y) > _misfit(ctx, pay, ls, y)  # the constraint is active


def test_a_physical_payload_keeps_the_least_squares_numbers(ctx):
    pay = get_effect("payload")
    good = pin.Inertia(0.8, np.array([0.01, -0.02, 0.15]), np.diag([2e-3, 2.5e-3, 1.5e-3])).toDynamicParameters()
    y = ctx.ev.Y_last @ good
    ls = pay.fit(ctx, y, np.arange(ctx.n))
    (f,) = _fit(ctx, ["payload"], y)
    assert not f.constrained
    np.testing.assert_array_equal(pay.coef(f), pay.coef(ls))


def test_a_friction_law_that_would_push_is_fitted_at_its_dissipative_bound_and_a_valid_one_is_not_touched(ctx):
    from franka_vs_gym.validation.effects import Fit

    vis = get_effect("viscous_friction")
    fv = ctx.config.friction.viscous
    c = np.where(np.arange(7) % 2 == 0, 0.3, -(fv + 2.0))  # even joints physical, odd joints a pushing law
    y = ctx.data.dq * c
    dq = np.linspace(-1, 1, 401)[:, None] * ctx.config.robot.limits.dq_max

    def power(coef):  # min over the velocity grid of tau_f dq per joint, the law as the model would have it
        fr = vis.friction(ctx.config.friction, Fit("viscous_friction", {"coef": np.asarray(coef)[:, None]}))
        return np.min(fr(dq) * dq, axis=0)

    ls = vis.fit(ctx, y, np.arange(ctx.n))
    assert np.all(power(vis.coef(ls)[:, 0])[1::2] < -1e-3)  # the least-squares law pushes the odd joints
    (f,) = _fit(ctx, ["viscous_friction"], y)
    assert f.constrained
    got = vis.coef(f)[:, 0]
    np.testing.assert_allclose(got[::2], vis.coef(ls)[::2, 0], rtol=1e-8)  # the valid joints: the LS numbers
    assert np.all(power(got) >= -1e-9)  # every joint's law dissipates (independent velocity grid)
    lower = got - 1e-3 * np.maximum(np.abs(got), 1e-2)
    assert np.all(power(lower)[1::2] < 0)  # and the odd joints sit on the bound: a little less would push
    # all physical: the fit is the least-squares one, number for number
    y = ctx.data.dq * 0.3
    (f,) = _fit(ctx, ["viscous_friction"], y)
    assert not f.constrained
    np.testing.assert_array_equal(vis.coef(f), vis.coef(vis.fit(ctx, y, np.arange(ctx.n))))


def test_a_delay_is_fitted_in_its_box(ctx):
    de = get_effect("delay")
    col = de.design(ctx, {})[:, :, 0]
    for d, want in ((0.4 * MIN_DELAY, MIN_DELAY), (1.5 * MAX_DELAY, MAX_DELAY), (0.01, None)):
        (f,) = _fitting.fit_jointly(ctx, [(de, None)], col * d, np.arange(ctx.n), refine=False)
        got = float(de.coef(f)[0])
        assert MIN_DELAY <= got <= MAX_DELAY
        if want is None:
            assert not f.constrained and abs(got - d) < 1e-6 * d
        else:
            assert got == pytest.approx(want, rel=1e-6)


def test_link_inertials_fitted_consistent_beside_a_tilt(ctx):
    """Link inertials beside a tilt, fitted jointly: the links constrained, every one physically consistent by
    pinocchio's pseudo-inertia with its mass in range; the tilt takes part as a free vector."""
    li = get_effect("link_inertials")
    b = li.basis(ctx.config)
    P = li._model_params(ctx.config)
    P[6] = P[6] - li._flange_params(ctx.config)
    bad = P.copy()
    bad[1:, 4:] *= -0.5  # negative moments: no rigid body has them
    dbeta = b["K"] @ (bad - P).ravel()
    y = li.design(ctx, {}) @ dbeta + ctx.ev.G @ np.array([0.05, -0.03, 0.3])
    f_li, _ = _fit(ctx, ["link_inertials", "gravity_tilt"], y)
    assert f_li.constrained
    links = np.asarray(f_li.theta["links"])
    for i, p in enumerate(links):
        w = _pseudo_eigs(p)
        assert w.min() > 0, (i, w)
        assert 0.5 * P[i, 0] * 0.999 <= p[0] <= (2.0 * P[i, 0] + 3.5) * 1.001
    # what was fitted is what the model takes: the coefficients are those of the applied links
    np.testing.assert_allclose(li.coef(f_li), b["K"] @ (links - P).ravel(), atol=1e-9)
    assert not li.problems(ctx, f_li)
