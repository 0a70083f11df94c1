"""Physical constraints inside the fit: the joint estimate of a set of effects over their physically valid values.

Each effect may describe its valid values by :meth:`~franka_vs_gym.validation.effects.base.Effect.feasible_set`: a
map from free coordinates ``x`` to its linear coefficients (an inertial body through the log-Cholesky parameters of
its pseudo-inertia), box bounds on ``x`` (a friction
coefficient that keeps the law dissipative, a delay in ``[MIN_DELAY, MAX_DELAY]``, a link's mass within its range),
an optional prior (the link inertials' pull towards the published links in the directions the log does not
determine) and whether the least-squares answer already satisfies the constraints.

A gravity tilt is not constrained yet: it is a free change of the gravity vector, and a fitted ``|g|`` far from
Earth's is still refused after the fit (the model's own check, ``model.checks.check_gravity``). Held on the sphere
``|g| = |g0|``, it could no longer stand in for links slightly heavier than the model's (on the Gaz log at 30 Hz the
free tilt fits ``|g|`` = 9.855 m/s^2, about 0.5 % heavier links, which no effect ``--add auto`` selects there
carries); a shared mass scale beside a tilt on the sphere is the open work.

:func:`constrained_fits` is the constrained fit of the set: when every member's least-squares answer is feasible it
returns the fits unchanged (today's numbers stay); otherwise it minimises the same data misfit,

    (n_eff / N) / mean_j(sigma_j^2) * sum_j || y_j - sum_i D_ij c_i(x_i) ||^2  (+ the priors),

jointly over every member's free coordinates (``scipy.optimize.least_squares``, trust-region reflective with the
bounds, warm-started from each member's least-squares answer projected onto its valid values; members without
constraints take part with free coefficients). ``y`` is the target
the set explains, ``D`` the effects' design columns (every joint weighed alike, as in the least-squares fits),
``sigma_j`` the log's noise floor per joint and ``n_eff`` the number of independent samples of the low-passed log
(2 cutoff T); the misfit is written through the normal
equations (``(c - c_ls)^T A (c - c_ls)`` plus a constant, ``c_ls`` the least-squares answer), so each
iteration is small. What is fitted is therefore always something the model can take: ``fit`` needs no rejection
after it. Members whose contribution is not linear in coefficients (the re-identified sigmoid, which bounds its own
parameters) are held at their fit.

:func:`tangent` gives each member's ``d coef / d x`` at the solution with the coordinates on an active bound removed:
the covariance of the constrained estimate is the unconstrained one projected onto these directions.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from franka_vs_gym.validation.effects.base import Context, Effect, Fit


@dataclass
class FeasibleSet:
    """An effect's valid values in free coordinates.

    ``x0`` (k,): the least-squares answer projected onto the valid values (inside ``lower``/``upper``);
    ``coef(x)``: the effect's linear coefficients, flattened in the order of :func:`columns`; ``make(x)``: the
    :class:`Fit` at ``x``; ``feasible``: the least-squares answer satisfies the constraints (then it is kept);
    ``prior(x)``: extra residuals (a regularisation), or None."""

    x0: np.ndarray
    coef: Callable[[np.ndarray], np.ndarray]
    make: Callable[[np.ndarray], Fit]
    feasible: bool
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None
    prior: Callable[[np.ndarray], np.ndarray] | None = None
    #: ``d coef / d x`` (p, k) and ``d prior / d x`` at ``x``, when the effect gives them (else forward differences)
    coef_jac: Callable[[np.ndarray], np.ndarray] | None = None
    prior_jac: Callable[[np.ndarray], np.ndarray] | None = None

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        k = len(self.x0)
        lo = np.full(k, -np.inf) if self.lower is None else np.asarray(self.lower, dtype=float)
        hi = np.full(k, np.inf) if self.upper is None else np.asarray(self.upper, dtype=float)
        return lo, hi


def columns(ctx: Context, e: Effect, fit: Fit, idx: np.ndarray) -> np.ndarray:
    """(m, 7, p) design columns of ``fit`` on samples ``idx``, one per coefficient the flattened ``coef`` holds: a
    shared effect's columns as they are; a per-joint effect's coefficient (j, q) as a column acting on joint j only,
    for j in ``fit.joints`` (joint-major)."""
    D = e.design(ctx, {k: v for k, v in fit.theta.items() if k != "coef"})[idx]
    if not e.per_joint:
        return D
    out = np.zeros((len(idx), 7, len(fit.joints) * D.shape[2]))
    k = 0
    for j in fit.joints:
        for q in range(D.shape[2]):
            out[:, j, k] = D[:, j, q]
            k += 1
    return out


def per_joint_coef(fit: Fit, x: np.ndarray, p: int) -> np.ndarray:
    """(7, p) coefficients of a per-joint fit whose joints' coefficients are ``x`` (joint-major), zeros elsewhere."""
    c = np.zeros((7, p))
    c[fit.joints] = np.asarray(x, dtype=float).reshape(len(fit.joints), p)
    return c


def weights(ctx: Context) -> np.ndarray:
    """(7,) the weight of a squared torque error per joint: the same on every joint, as in the least-squares fits
    the constrained fit constrains (``Effect.fit`` weighs every joint's Nm alike), scaled to a chi-square,
    (n_eff / N) / mean(sigma_j^2) (noise floors sigma_j, floored at 1 mNm; n_eff = 2 cutoff T independent samples
    of the low-passed log), so that a prior (the link inertials') weighs against the data as in
    :func:`~franka_vs_gym.validation.inertials.consistent_links`."""
    sig = np.maximum(np.asarray(ctx.data.noise, dtype=float), 1e-3)
    n_eff = max(2.0 * ctx.data.settings.cutoff * ctx.n / ctx.data.settings.rate, 1.0)
    return np.full(7, (n_eff / ctx.n) / float(np.mean(sig ** 2)))


def constrained_fits(ctx: Context, effects: list[Effect], fits: list[Fit], y: np.ndarray,
                     idx: np.ndarray | None = None) -> list[Fit]:
    """The fits of ``effects`` on target ``y`` (N, 7) (samples ``idx``, default all) constrained to physically
    valid values (see the module docstring): the fits themselves when every least-squares answer is valid."""
    idx = np.arange(ctx.n) if idx is None else np.asarray(idx)
    sets = [e.feasible_set(ctx, f) for e, f in zip(effects, fits, strict=True)]
    if all(s is None or s.feasible for s in sets):
        return list(fits)
    # members without constraints take part with their coefficients free, when their contribution is linear in them
    sets = [s if s is not None or type(e).contribution is not Effect.contribution else _free_set(e, f)
            for e, f, s in zip(effects, fits, sets, strict=True)]
    from scipy.optimize import least_squares

    free = [i for i, s in enumerate(sets) if s is not None]
    held = [i for i, s in enumerate(sets) if s is None]
    target = y[idx] - sum((effects[i].contribution(ctx, fits[i])[idx] for i in held), np.zeros((len(idx), 7)))
    cols = [columns(ctx, effects[i], fits[i], idx) for i in free]
    X = np.concatenate(cols, axis=2)  # (m, 7, P)
    sw = np.sqrt(weights(ctx))
    Xf = (X * sw[None, :, None]).reshape(-1, X.shape[2])
    A = Xf.T @ Xf
    b = Xf.T @ (target * sw[None, :]).ravel()
    lam, V = np.linalg.eigh(0.5 * (A + A.T))
    keep = lam > 1e-12 * max(float(lam.max(initial=0.0)), 1e-300)
    R = (V[:, keep] * np.sqrt(lam[keep])).T  # R^T R = A on its range
    c_ls = V[:, keep] @ ((V[:, keep].T @ b) / lam[keep])
    r_ls = R @ c_ls
    sizes = [len(sets[i].x0) for i in free]
    cuts = np.cumsum([0, *sizes])
    lo = np.concatenate([sets[i].bounds()[0] for i in free])
    hi = np.concatenate([sets[i].bounds()[1] for i in free])
    x0 = np.clip(np.concatenate([sets[i].x0 for i in free]), lo, hi)
    with np.errstate(invalid="ignore"):  # a start on a bound moves just inside it (what the solver needs)
        x0 = np.where(np.isfinite(lo) & (x0 <= lo), lo + 1e-12 * np.maximum(1.0, np.abs(lo)), x0)
        x0 = np.where(np.isfinite(hi) & (x0 >= hi), hi - 1e-12 * np.maximum(1.0, np.abs(hi)), x0)

    def parts(x):
        return [x[cuts[k]:cuts[k + 1]] for k in range(len(free))]

    def resid(x):
        xs = parts(x)
        c = np.concatenate([sets[i].coef(xk) for i, xk in zip(free, xs, strict=True)])
        out = [R @ c - r_ls]
        out += [sets[i].prior(xk) for i, xk in zip(free, xs, strict=True) if sets[i].prior is not None]
        return np.concatenate(out)

    def jac(x):
        xs = parts(x)
        blocks = [_jac(sets[i].coef, sets[i].coef_jac, xk) for i, xk in zip(free, xs, strict=True)]
        rows = [R @ _block_diag(blocks)]
        for k, (i, xk) in enumerate(zip(free, xs, strict=True)):
            if sets[i].prior is not None:
                pj = _jac(sets[i].prior, sets[i].prior_jac, xk)
                full = np.zeros((pj.shape[0], len(x)))
                full[:, cuts[k]:cuts[k + 1]] = pj
                rows.append(full)
        return np.vstack(rows)

    sol = least_squares(resid, x0, jac=jac, bounds=(lo, hi), method="trf", x_scale="jac", xtol=1e-10, ftol=1e-10,
                        gtol=1e-10, max_nfev=200)
    out = list(fits)
    for i, xk in zip(free, parts(sol.x), strict=True):
        f = sets[i].make(xk)
        f.constrained = True
        out[i] = f
    return out


def _free_set(e: Effect, fit: Fit) -> FeasibleSet:
    """An unconstrained effect's coefficients, free (its least-squares answer is feasible)."""
    c = np.asarray(fit.theta["coef"], dtype=float)
    if not e.per_joint:
        return box_set(fit, c.ravel())
    c = c.reshape(7, -1)
    return box_set(fit, c[fit.joints].ravel(), p=c.shape[1])


def _jac(fun, given, x: np.ndarray) -> np.ndarray:
    """``d fun / d x`` at ``x``: the effect's own, else forward differences (steps 1e-7 relative)."""
    if given is not None:
        return np.asarray(given(x), dtype=float)
    f0 = np.asarray(fun(x), dtype=float)
    out = np.empty((len(f0), len(x)))
    for k in range(len(x)):
        h = 1e-7 * max(1.0, abs(float(x[k])))
        xp = np.array(x, dtype=float, copy=True)
        xp[k] += h
        out[:, k] = (np.asarray(fun(xp), dtype=float) - f0) / h
    return out


def _block_diag(blocks: list[np.ndarray]) -> np.ndarray:
    out = np.zeros((sum(b.shape[0] for b in blocks), sum(b.shape[1] for b in blocks)))
    r = c = 0
    for b in blocks:
        out[r:r + b.shape[0], c:c + b.shape[1]] = b
        r, c = r + b.shape[0], c + b.shape[1]
    return out


def tangent(ctx: Context, e: Effect, fit: Fit) -> np.ndarray | None:
    """(p, k) ``d coef / d x`` of a constrained fit at its value, the coordinates on an active bound left out (their
    value is fixed by the constraint); None when the effect has no constraint or the fit was not constrained."""
    if not fit.constrained:
        return None
    s = e.feasible_set(ctx, fit)
    if s is None:
        return None
    x = s.x0
    lo, hi = s.bounds()
    with np.errstate(invalid="ignore"):  # (an infinite bound is never active)
        free = ~((np.isfinite(lo) & (x <= lo + 1e-7 * np.maximum(1.0, np.abs(lo))))
                 | (np.isfinite(hi) & (x >= hi - 1e-7 * np.maximum(1.0, np.abs(hi)))))
    return _jac(s.coef, s.coef_jac, x)[:, free]


# ---------------------------------------------------------------------------------------------- the sets
def box_set(fit: Fit, x0: np.ndarray, lower=None, upper=None, p: int | None = None) -> FeasibleSet:
    """Coefficients that are their own coordinates, bounded by a box: a per-joint effect's ``p`` coefficients on each
    of ``fit.joints`` (joint-major; ``p`` None: a shared effect's coefficients as they are)."""
    x0 = np.asarray(x0, dtype=float)
    lo = np.full(len(x0), -np.inf) if lower is None else np.asarray(lower, dtype=float)
    hi = np.full(len(x0), np.inf) if upper is None else np.asarray(upper, dtype=float)

    def make(x):
        c = per_joint_coef(fit, x, p) if p else np.asarray(x, dtype=float).copy()
        return Fit(fit.effect, {**fit.theta, "coef": c}, list(fit.joints))

    return FeasibleSet(np.clip(x0, lo, hi), lambda x: np.asarray(x, dtype=float), make,
                       bool(np.all((x0 >= lo) & (x0 <= hi))), lo, hi)


def body_set(fit: Fit, coef: np.ndarray, base: np.ndarray, max_mass: float | None) -> FeasibleSet:
    """A body ``base + coef`` (pinocchio's 10 dynamic parameters) physically consistent: the log-Cholesky parameters
    of its pseudo-inertia (:mod:`~franka_vs_gym.validation.inertials`), its mass at most ``max_mass`` (None: no
    bound). Feasible: the least-squares body's pseudo-inertia is positive definite and its mass within the bound."""
    from franka_vs_gym.validation.inertials import nearest_consistent, params_from_theta, pseudo_inertia

    body = base + coef
    ev = np.linalg.eigvalsh(pseudo_inertia(body))
    upper = np.full(10, np.inf)
    if max_mass is not None:
        upper[0] = 0.5 * math.log(max_mass)  # mass = exp(2 alpha)
    feasible = bool(ev[0] > 1e-9 * max(float(ev[-1]), 1e-12)) and (max_mass is None or body[0] <= max_mass)

    def to_coef(x):
        return params_from_theta(x) - base

    return FeasibleSet(nearest_consistent(body), to_coef,
                       lambda x: Fit(fit.effect, {**fit.theta, "coef": to_coef(x)}, list(fit.joints)), feasible,
                       upper=upper)


def links_set(fit: Fit, K: np.ndarray, old: np.ndarray, new: np.ndarray, feasible: bool,
              max_payload: float) -> FeasibleSet:
    """Seven physically consistent links whose base-parameter change is ``K (pi - old)``: their log-Cholesky
    parameters (70), started at ``new`` (7, 10), masses within [0.5, 2] of ``old``'s (link 7's up to twice its own
    plus ``max_payload``: a body held at the flange is part of its parameters), with the prior of
    :func:`~franka_vs_gym.validation.inertials.consistent_links` towards ``old`` in the directions the log does not
    determine; the fit's ``theta["links"]`` is the links. None when ``old`` is not consistent itself."""
    from franka_vs_gym.validation.inertials import link_prior, params_from_theta, params_jacobian, theta_from_params

    try:
        prior, prior_jac = link_prior(old)
    except ValueError:  # the model's own links are not consistent: nothing to constrain towards
        return None
    m = old[:, 0]
    lower = np.full((7, 10), -np.inf)
    upper = np.full((7, 10), np.inf)
    lower[:, 0] = 0.5 * np.log(0.5 * m)
    upper[:, 0] = 0.5 * np.log(2.0 * m)
    upper[6, 0] = 0.5 * math.log(2.0 * m[6] + max_payload)

    def coef(x):
        return K @ (params_from_theta(np.asarray(x).reshape(7, 10)) - old).ravel()

    def make(x):
        links = params_from_theta(np.asarray(x).reshape(7, 10))
        return Fit(fit.effect, {**fit.theta, "coef": K @ (links - old).ravel(), "links": links}, list(fit.joints))

    x0 = np.array([theta_from_params(p) for p in new]).ravel()
    return FeasibleSet(x0, coef, make, feasible, lower.ravel(), upper.ravel(), prior,
                       coef_jac=lambda x: K @ params_jacobian(x), prior_jac=prior_jac)


def constrained_projection(params: list, live: np.ndarray, gram: np.ndarray, tangents: list) -> np.ndarray | None:
    """(L, L) the map from the unconstrained to the constrained estimate's first-order error over the live
    parameters of :func:`~franka_vs_gym.validation.uncertainty.confidence`: ``B (B^T H B)^+ B^T H`` with ``H`` the
    Gram matrix of the live parameters' columns and ``B`` the directions the constraints leave free (each constrained
    fit's :func:`tangent`, its coefficients in the order the parameters list them; identity for every other
    parameter). None when nothing is constrained or a constrained fit's coefficients are not those listed."""
    if not any(t is not None for t in tangents):
        return None
    blocks = []
    for k, p in enumerate(params):
        if p.key != "coef" or p.term >= len(tangents) or tangents[p.term] is None:
            col = np.zeros((len(params), 1))
            col[k, 0] = 1.0
            blocks.append(col)
    for ti, t in enumerate(tangents):
        if t is None:
            continue
        rows = [k for k, p in enumerate(params) if p.term == ti and p.key == "coef"]
        if len(rows) != t.shape[0]:
            return None
        b = np.zeros((len(params), t.shape[1]))
        b[rows] = t
        blocks.append(b)
    B = np.concatenate(blocks, axis=1)[live]
    B = B[:, np.any(B != 0, axis=0)]
    return B @ np.linalg.pinv(B.T @ gram @ B, hermitian=True) @ B.T @ gram


__all__ = ["FeasibleSet", "body_set", "box_set", "columns", "constrained_fits", "constrained_projection", "links_set",
           "per_joint_coef", "tangent", "weights"]
