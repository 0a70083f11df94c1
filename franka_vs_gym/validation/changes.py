"""Changes of the model during a log (a grasp, a tool change, a sensor re-zeroing): found from the residual.

A change at time ``t_c`` is an effect that acts only after ``t_c`` (:class:`After`: the effect's regressor columns
multiplied by the step ``t > t_c``), fitted *together with* the same effect over the whole log, so that the
whole-log part takes what is common and the step part what differs before and after. The scan
(:func:`scan`) tries every ``t_c`` on a grid of ``GRID`` times between 10 % and 90 % of the log for each kind of
:data:`KINDS` at once from cumulative sums of the normal equations (whitened by the noise floor per joint), so it
costs a few small solves per time, not a pass over the data. The best time is kept when its evidence
``sum_j N_eff_j ln(MSE0_j / MSE1_j) - p ln(N_eff) - ln(GRID)`` (``N_eff`` the effective sample size of the residual
under its autocorrelation, ``p`` the step's parameters, ``ln(GRID)`` for the times tried) exceeds ``SCORE_MIN``
and the step removes at least ``PRACTICAL`` noise floors RMS on some joint. A slow drift (a warm-up) is
distinguished from a step by fitting the same effect's columns times a linear ramp in time instead: the step must
beat the ramp by ``SCORE_MIN``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from franka_vs_gym.validation.compare import progress
from franka_vs_gym.validation.effects import Context, Effect, Fit, get_effect
from franka_vs_gym.validation.results import ModelChange
from franka_vs_gym.validation.selection import Engine, SetFit, Term, n_eff

KINDS = ("payload", "torque_offset")
GRID = 120
SCORE_MIN = 30.0
PRACTICAL = 0.5


class After(Effect):
    """``base`` acting only after ``t_c`` (s, the processed log's time): its columns times the step t > t_c.
    Internal to the diagnosis (not registered): what changes mid-log."""

    injectable = False

    def __init__(self, base: Effect, t_c: float) -> None:
        self.base, self.t_c = base, float(t_c)
        self.name = f"{base.name}_after"
        self.per_joint, self.n_params = base.per_joint, base.n_params

    def design(self, ctx, shape):
        m = (ctx.data.time > self.t_c).astype(float)
        return ctx.cached(("after", self.base.name, self.t_c),
                          lambda: np.asarray(self.base.design(ctx, shape)) * m[:, None, None])

    def shape_key(self, shape):
        return (self.t_c,)

    def make_fit(self, ctx, coef, shape, joints):
        f = self.base.make_fit(ctx, coef, shape, joints)
        return Fit(self.name, f.theta, f.joints)

    def public(self, fit):
        return self.base.public(Fit(self.base.name, fit.theta, fit.joints))


@dataclass
class Found:
    effect: str
    t_c: float
    score: float
    removed: np.ndarray  # (7,) Nm RMS the step removes


def _designs(ctx: Context, kind: str, idx: np.ndarray) -> np.ndarray:
    e = get_effect(kind)
    return np.asarray(e.design(ctx, e.shape(ctx, ctx.residual)), dtype=float)[idx]


def scan(ctx: Context, residual: np.ndarray, noise: np.ndarray) -> Found | None:
    """The strongest significant change of :data:`KINDS` in ``residual`` (N, 7) Nm, or None."""
    idx = ctx.coarse
    t = ctx.data.time[idx]
    n = len(idx)
    if n < 50:
        return None
    sig = np.maximum(np.asarray(noise, dtype=float), 1e-3)
    r = residual[idx] / sig
    lo, hi = int(0.1 * n), int(0.9 * n)
    cuts = np.unique(np.linspace(lo, hi, GRID).astype(int))
    best: Found | None = None
    tn = (t - t.mean()) / max(np.ptp(t), 1e-9)
    for kind in KINDS:
        D = _designs(ctx, kind, idx) / sig[None, :, None]  # (n, 7, p)
        per_joint = get_effect(kind).per_joint
        if per_joint:  # one column per joint: (n, 7, 7) block-diagonal
            p0 = D.shape[2]
            E = np.zeros((n, 7, 7 * p0))
            for j in range(7):
                E[:, j, j * p0:(j + 1) * p0] = D[:, j]
            D = E
        p = D.shape[2]
        outer = np.einsum("njp,njq->npq", D, D)
        dr = np.einsum("njp,nj->np", D, r)
        S_rev = np.cumsum(outer[::-1], axis=0)[::-1]  # sum over k >= i
        b_rev = np.cumsum(dr[::-1], axis=0)[::-1]
        S0, b0 = S_rev[0], b_rev[0]
        reg = 1e-9 * np.trace(S0) / p * np.eye(p)
        g_whole = float(b0 @ np.linalg.solve(S0 + reg, b0))
        gains = np.empty(len(cuts))
        for i, c in enumerate(cuts):
            St, bt = S_rev[c], b_rev[c]
            M = np.block([[S0, St], [St, St]]) + 1e-9 * np.trace(S0) / p * np.eye(2 * p)
            bb = np.concatenate([b0, bt])
            gains[i] = float(bb @ np.linalg.solve(M, bb)) - g_whole
        c = int(cuts[int(np.argmax(gains))])
        step = (np.arange(n) >= c).astype(float)

        def per_joint_mse(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            th = np.linalg.lstsq(X.reshape(-1, X.shape[2]), r.reshape(-1), rcond=None)[0]
            res = r - np.einsum("njp,p->nj", X, th)
            return np.mean(res ** 2, axis=0), res

        mse0, res0 = per_joint_mse(D)
        mse1, res1 = per_joint_mse(np.concatenate([D, D * step[:, None, None]], axis=2))
        mse_ramp, _ = per_joint_mse(np.concatenate([D, D * tn[:, None, None]], axis=2))
        # the effective sample size of what remains with the step, or without it, whichever is larger (a step left
        # in the residual is itself what makes it look strongly correlated)
        ne = np.maximum(np.maximum(np.asarray(n_eff(res0)), np.asarray(n_eff(res1))), 2.0)
        ln = float(np.log(ne.mean()))
        score = float(np.sum(ne * np.log(np.maximum(mse0, 1e-30) / np.maximum(mse1, 1e-30)))) - p * ln \
            - float(np.log(len(cuts) * len(KINDS)))
        over_ramp = float(np.sum(ne * np.log(np.maximum(mse_ramp, 1e-30) / np.maximum(mse1, 1e-30))))
        removed = np.sqrt(np.maximum(mse0 - mse1, 0.0)) * sig
        if (score > SCORE_MIN and over_ramp > SCORE_MIN and np.any(removed >= PRACTICAL * sig)
                and (best is None or score > best.score)):
            t_c = 0.5 * (float(t[c - 1]) + float(t[c]))
            best = Found(kind, t_c, score, removed)
    return best


def describe(kind: str, whole: dict[str, Any] | None, step: dict[str, Any]) -> tuple[str, dict, dict]:
    """What differs before and after, in words, and the parameters before and after."""
    if kind == "payload":
        m0 = float((whole or {}).get("mass_kg", 0.0) or 0.0)
        dm = float(step.get("mass_kg", 0.0))
        after = {"payload_mass_kg": round(m0 + dm, 4)}
        if "com_flange_m" in step:
            after["payload_com_flange_m"] = step["com_flange_m"]
        before = {"payload_mass_kg": round(m0, 4)}
        if dm > 0:
            com = np.round(np.asarray(step.get("com_flange_m", []), dtype=float), 3).tolist()
            what = f"a payload of {dm:.2f} kg appears (centre of mass {com} m from the flange)"
        else:
            what = f"a payload of {-dm:.2f} kg is released"
        return what, before, after
    o0 = np.asarray((whole or {}).get("offset_Nm", np.zeros(7)), dtype=float)
    do = np.asarray(step.get("offset_Nm", np.zeros(7)), dtype=float)
    js = [j for j in range(7) if abs(do[j]) > 0]
    what = "the torque offsets change by " + ", ".join(f"{do[j]:+.3f} Nm on joint {j}" for j in js)
    return what, {"offset_Nm": np.round(o0, 4).tolist()}, {"offset_Nm": np.round(o0 + do, 4).tolist()}


def model_changes(ctx: Context, eng: Engine, sel: Any, chosen: list[Term], cur: SetFit, noise: np.ndarray,
                   forced: list[Term], verbose: bool) -> tuple[list[Term], SetFit, list[ModelChange]]:
    """Scan the residual of the selected set for a change of the model during the log
    (:mod:`~franka_vs_gym.validation.changes`); when one is found, select again with the change in the model (so
    the effects present all along are named on a residual without the step) and describe it. ``sel``: the
    diagnosis' selector (its ``run``)."""
    found = scan(ctx, eng.residual(cur), noise)
    if found is None:
        return chosen, cur, []
    progress(f"the model changes at t = {found.t_c:.2f} s ({found.effect}): selecting again with the change", verbose)
    base = get_effect(found.effect)
    step = After(base, found.t_c)
    joints = None
    if base.per_joint:
        joints = [j for j in range(7) if found.removed[j] >= 0.25 * noise[j]] or list(range(7))
    term = Term(step, {}, joints)
    _, chosen2, cur2 = sel.run(True, forced=forced + [term])
    k = next(i for i, t in enumerate(chosen2) if t.effect is step)  # (its joints may have been pruned)
    whole = next((f for t, f in zip(chosen2, cur2.fits, strict=True) if t.effect is base), None)
    what, before, after = describe(found.effect, base.public(whole) if whole is not None else None,
                                      step.public(cur2.fits[k]))
    return chosen2, cur2, [ModelChange(found.t_c, what, before, after)]


__all__ = ["After", "Found", "KINDS", "describe", "model_changes", "scan"]
