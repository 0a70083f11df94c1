"""Friction laws with a step at zero velocity whose shape is fitted: Gaz's sigmoid (a replacement of the model's,
fitted by Levenberg-Marquardt on its three parameters per joint) and direction-dependent (asymmetric) Coulomb
friction, which the model applies through its sigmoid."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from franka_vs_gym.model.config import Friction
from franka_vs_gym.model.friction import (
    gaz_sigmoid,
    sigmoid_levels,
)
from franka_vs_gym.validation.effects.base import (
    COULOMB_VC,
    SIG_PHI2,
    SIG_PHI3,
    Context,
    Effect,
    Fit,
    NotApplicable,
    _joint_coef,
    _lstsq_joints,
    _model_step_levels,
    _tau_max,
)
from franka_vs_gym.validation.evaluate import sigmoid_friction


def _sig(u):
    return 1.0 / (1.0 + np.exp(-np.clip(u, -60, 60)))


def _sigmoid_lm(dq: np.ndarray, y: np.ndarray, p1: np.ndarray, p2: np.ndarray, p3: np.ndarray,
                iters: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Levenberg-Marquardt steps on (phi1, phi2, phi3) of every joint at once (dq, y: (m, 7)); keeps phi1 >= 0,
    phi2 in [0.5, 400] s/rad, |phi3| <= 0.3 rad/s."""
    p = np.stack([p1, p2, p3], axis=1).astype(float)  # (7, 3)
    lam = np.full(7, 1e-2)

    def model(p):
        u = p[:, 1] * (dq + p[:, 2])
        u0 = p[:, 1] * p[:, 2]
        s, s0 = _sig(u), _sig(u0)
        return p[:, 0] * (s - s0), s, s0

    f, s, s0 = model(p)
    sse = np.sum((y - f) ** 2, axis=0)
    lo, hi = np.array([0.0, 0.5, -0.3]), np.array([np.inf, 400.0, 0.3])
    for _ in range(iters):
        ds, ds0 = s * (1 - s), s0 * (1 - s0)
        J = np.stack([s - s0, p[:, 0] * (ds * (dq + p[:, 2]) - ds0 * p[:, 2]), p[:, 0] * p[:, 1] * (ds - ds0)],
                     axis=2)  # (m, 7, 3)
        A = np.einsum("mja,mjb->jab", J, J)
        g = np.einsum("mja,mj->ja", J, y - f)
        D = np.einsum("jaa->ja", A)
        step = np.linalg.solve(A + lam[:, None, None] * np.einsum("ja,ab->jab", D + 1e-12, np.eye(3)), g[..., None])
        cand = np.clip(p + step[..., 0], lo, hi)
        fc, _, _ = model(cand)
        ssec = np.sum((y - fc) ** 2, axis=0)
        ok = ssec < sse
        p[ok] = cand[ok]
        lam = np.where(ok, lam * 0.3, lam * 10.0)
        f, s, s0 = model(p)
        sse = np.sum((y - f) ** 2, axis=0)
    return p[:, 0], p[:, 1], p[:, 2]


class SigmoidFriction(Effect):
    """Gaz et al. 2019 sigmoid friction ``phi1/(1+exp(-phi2 (dq+phi3))) - phi1/(1+exp(-phi2 phi3))`` per joint: a
    Stribeck-like rounded step whose width is 1/phi2 and whose centre -phi3 may be off zero, so the levels differ
    by direction (an asymmetric friction). ``diagnose`` fits an additional sigmoid (its shape chosen on the
    residual, its height linear); ``fit`` re-identifies the model's sigmoid (replaces it on the joints selected).

    Plausible: phi1 > 0 and < 0.25 tau_max Nm; phi2 in [0.5, 400] s/rad; abs(phi3) <= 0.3 rad/s (Gaz et al.:
    phi1 0.03-0.55 Nm, phi2 5-40 s/rad, phi3 -0.03-0.06 rad/s).
    """

    name, aliases = "sigmoid_friction", ("gaz_friction",)
    n_params = 3
    description = "Gaz et al. sigmoid friction (a Stribeck-like rounded, possibly off-centre step)"
    signature = "a rounded step in residual vs dq whose width is phi2's inverse, possibly off-centre (phi3)"
    plausible = "phi1 > 0 and < 0.25 tau_max (Nm), phi2 in [0.5, 400] s/rad, abs(phi3) <= 0.3 rad/s"

    lof_constant_height = True
    lof_signals = ("dq",)

    def shape(self, ctx, target):
        basis = ctx.sigmoid_basis()  # (g, nc, 7)
        t = target[ctx.coarse]
        num = np.einsum("gmj,mj->gj", basis, t)
        den = ctx.cached("sigmoid_basis_norms", lambda: np.einsum("gmj,gmj->gj", basis, basis)) + 1e-12
        best = np.argmax(num ** 2 / den, axis=0)
        cols = np.arange(7)
        p1 = num[best, cols] / den[best, cols]
        p2 = SIG_PHI2[best // len(SIG_PHI3)]
        p3 = SIG_PHI3[best % len(SIG_PHI3)]
        sign = np.where(p1 < 0, -1.0, 1.0)
        _, p2, p3 = _sigmoid_lm(ctx.data.dq[ctx.coarse], t * sign, np.abs(p1), p2, p3, iters=5)
        return {"phi2": p2, "phi3": p3}

    def design(self, ctx, shape):
        """Columns: the added sigmoid of the chosen shape, and the model's own sigmoid (its height re-scaled), so a
        change of the model's sigmoid (height and width) is representable linearly."""
        p2, p3 = np.asarray(shape["phi2"]), np.asarray(shape["phi3"])
        new = gaz_sigmoid(ctx.data.dq, 1.0, p2, p3)
        if not ctx.config.friction.phi1.any():
            return new[:, :, None]
        return np.stack([new, ctx.base_sigmoid], axis=2)

    def fit(self, ctx, y, idx):
        """Replacement fit (the model's sigmoid re-identified): theta phi1, phi2, phi3 (7,) each."""
        target = y + ctx.base_sigmoid
        mask = np.zeros(ctx.n, dtype=bool)
        mask[idx] = True
        sel = mask[ctx.coarse]
        basis = ctx.sigmoid_basis()[:, sel, :]
        t = target[ctx.coarse][sel]
        num = np.einsum("gmj,mj->gj", basis, t)
        den = np.einsum("gmj,gmj->gj", basis, basis) + 1e-12
        gain = np.where(num > 0, num ** 2 / den, -np.inf)
        best = np.argmax(gain, axis=0)
        cols = np.arange(7)
        p1 = np.where(np.isfinite(gain[best, cols]), num[best, cols] / den[best, cols], 0.0)
        p2 = SIG_PHI2[best // len(SIG_PHI3)]
        p3 = SIG_PHI3[best % len(SIG_PHI3)]
        p1, p2, p3 = _sigmoid_lm(ctx.data.dq[ctx.coarse][sel], t, p1, p2, p3)
        return Fit(self.name, {"phi1": p1, "phi2": p2, "phi3": p3, "replace": True})

    def make_fit(self, ctx, coef, shape, joints):
        # the additive form of diagnose: an extra sigmoid of height coef[:, 0] on top of the model's, whose height
        # changes by the factor coef[:, 1]
        c = np.asarray(coef, float).reshape(7, -1)
        if c.shape[1] == 1:
            c = np.column_stack([c, np.zeros(7)])
        return Fit(self.name, {"coef": c, **shape, "replace": False},
                   list(range(7)) if joints is None else list(joints))

    def _replacement(self, ctx: Context, fit: Fit) -> Friction:
        fr = ctx.config.friction
        new = Friction(fr.phi1.copy(), fr.phi2.copy(), fr.phi3.copy())
        j = fit.joints
        new.phi1[j], new.phi2[j], new.phi3[j] = (np.asarray(fit.theta[k])[j] for k in ("phi1", "phi2", "phi3"))
        return new

    def contribution(self, ctx, fit):
        if not fit.theta.get("replace"):
            c = _joint_coef(fit, 2)
            p2, p3 = np.asarray(fit.theta["phi2"]), np.asarray(fit.theta["phi3"])
            return gaz_sigmoid(ctx.data.dq, 1.0, p2, p3) * c[:, 0] + ctx.base_sigmoid * c[:, 1]
        return sigmoid_friction(self._replacement(ctx, fit), ctx.data.dq) - ctx.base_sigmoid

    def refine(self, ctx, y, fit):
        from scipy.optimize import least_squares

        if not fit.theta.get("replace"):
            return fit
        th = {k: np.array(v, dtype=float).copy() if k != "replace" else v for k, v in fit.theta.items()}
        dq_all = ctx.data.dq
        tgt_all = y + ctx.base_sigmoid
        sub = np.arange(0, ctx.n, 2)
        for j in range(7):
            if th["phi1"][j] <= 0:
                continue
            dq, tgt = dq_all[sub, j], tgt_all[sub, j]

            def res(p, dq=dq, tgt=tgt):
                p1, lp2, p3 = p
                p2 = math.exp(lp2)
                return gaz_sigmoid(dq, p1, p2, p3) - tgt

            x0 = [th["phi1"][j], math.log(min(max(th["phi2"][j], 0.51), 399.0)), float(np.clip(th["phi3"][j], -0.29,
                                                                                                  0.29))]
            try:
                r = least_squares(res, x0, bounds=([0, math.log(0.5), -0.3], [_tau_max(ctx)[j], math.log(400), 0.3]),
                                  max_nfev=60)
                th["phi1"][j], th["phi2"][j], th["phi3"][j] = r.x[0], math.exp(r.x[1]), r.x[2]
            except ValueError:
                pass
        return Fit(self.name, th, fit.joints)

    def problems(self, ctx, fit):
        if fit.theta.get("replace"):
            p1 = np.asarray(fit.theta["phi1"])
            what = "sigmoid height phi1"
        else:
            c = _joint_coef(fit, 2)
            p1 = ctx.config.friction.phi1 * (1 + c[:, 1]) + c[:, 0]
            what = "total sigmoid height (model + added)"
        out = {j: f"{what} = {p1[j]:.3g} Nm must be > 0" for j in fit.joints if p1[j] <= 0}
        tm = _tau_max(ctx)
        out |= {j: f"{what} = {p1[j]:.3g} Nm is implausibly large" for j in fit.joints if p1[j] > 0.25 * tm[j]}
        return out

    def apply(self, config, fit):
        if not fit.theta.get("replace"):
            raise NotApplicable("an additive sigmoid is refitted as a replacement by fit_effects before applying")
        fr = Friction.from_dict(config.friction.to_dict())
        j = fit.joints
        fr.phi1[j], fr.phi2[j], fr.phi3[j] = (np.asarray(fit.theta[k])[j] for k in ("phi1", "phi2", "phi3"))
        return config.copy(friction=fr)

    def inject(self, plant, rng, magnitude):
        base = Friction()
        phi1 = base.phi1 * (1 + 0.8 * magnitude * rng.uniform(0.7, 1.3, 7))
        phi2 = base.phi2 * rng.uniform(0.6, 1.4, 7)
        fr = Friction.from_dict(plant.config.friction.to_dict())
        fr.phi1, fr.phi2, fr.phi3 = phi1, phi2, base.phi3.copy()
        plant.config = plant.config.copy(friction=fr)
        return {"phi1_Nm": phi1.tolist(), "phi2_s_per_rad": phi2.tolist(), "phi3_rad_per_s": base.phi3.tolist()}

    def public(self, fit):
        out: dict[str, Any] = {}
        if fit.theta.get("replace"):
            keys = (("phi1", "Nm"), ("phi2", "s_per_rad"), ("phi3", "rad_per_s"))
            for k, unit in keys:
                v = np.full(7, np.nan)
                v[fit.joints] = np.asarray(fit.theta[k])[fit.joints]
                out[f"{k}_{unit}"] = [None if not np.isfinite(x) else round(float(x), 6) for x in v]
            return out
        c = _joint_coef(fit, 2)
        out["added_phi1_Nm"] = np.round(c[:, 0], 6).tolist()
        out["model_phi1_change"] = np.round(c[:, 1], 6).tolist()
        for k, unit in (("phi2", "s_per_rad"), ("phi3", "rad_per_s")):
            v = np.asarray(fit.theta[k], float)
            out[f"{k}_{unit}"] = [round(float(v[j]), 6) if j in fit.joints else None for j in range(7)]
        return out


class AsymmetricFriction(Effect):
    """Direction-dependent Coulomb friction: ``F_plus`` while the joint turns positively, ``F_minus`` while it
    turns negatively, ``tau_f = F_plus max(s, 0) + F_minus min(s, 0)`` with ``s = tanh(dq / v_c)``. Harmonic drives
    show it (Gaz et al. 2019 model it with the sigmoid's centre phi3; Tadese/Wolf et al. measure it on Franka joints).

    Signature: a step at dq = 0 whose two levels differ in magnitude. Away from rest it is indistinguishable from a
    symmetric Coulomb step plus a torque offset; only the samples near zero velocity tell them apart, so on logs
    that rarely stop it forms a collinear group with ``coulomb_friction`` + ``torque_offset``.
    Plausible: both levels >= 0 and < 0.25 tau_max Nm. The model applies it through its sigmoid (the law's
    direction-dependent term): a joint without one gets a sigmoid with the two levels; a joint with one gets the
    sum of its levels and the fitted ones, keeping its width (see :meth:`apply`).
    """

    name, aliases = "asymmetric_friction", ("asymmetric",)
    n_params = 2
    description = "direction-dependent Coulomb friction (F_plus for dq > 0, F_minus for dq < 0)"
    signature = "a step at zero velocity whose positive and negative levels differ"
    plausible = "F_plus, F_minus >= 0 (total) and < 0.25 tau_max (Nm)"

    lof_constant_height = True
    lof_signals = ("dq",)

    def shape(self, ctx, target):
        # the smoothing velocity is chosen with the effect's own two levels (a symmetric tanh would misjudge a step
        # whose levels have the same sign, i.e. a mostly one-sided change of friction)
        fr = ctx.config.friction
        if fr.coulomb.any():
            return {"coulomb_vel": fr.coulomb_vel}
        dq, y = ctx.data.dq[ctx.coarse], target[ctx.coarse]
        best, best_sse = COULOMB_VC[0], np.inf
        for vc in COULOMB_VC:
            s = np.tanh(dq / vc)
            a, b = np.maximum(s, 0.0), np.minimum(s, 0.0)
            # per joint 2x2 normal equations (a and b do not overlap, so they decouple)
            ta = _lstsq_joints(a, y)
            tb = _lstsq_joints(b, y)
            sse = float(np.sum((y - a * ta - b * tb) ** 2))
            if sse < best_sse:
                best, best_sse = vc, sse
        return {"coulomb_vel": best}

    def design(self, ctx, shape):
        vc = float(shape["coulomb_vel"])

        def make():
            s = np.tanh(ctx.data.dq / vc)
            return np.stack([np.maximum(s, 0.0), np.minimum(s, 0.0)], axis=2)
        return ctx.cached(("asym", vc), make)

    def problems(self, ctx, fit):
        c = _joint_coef(fit, 2)
        lp, lm = _model_step_levels(ctx)  # the model's own step levels in each direction (sigmoid and Coulomb)
        out = {}
        for j in fit.joints:
            lo = min(lp[j] + c[j, 0], lm[j] + c[j, 1])
            hi = max(lp[j] + c[j, 0], lm[j] + c[j, 1])
            if lo < 0:
                out[j] = f"a negative friction level {lo:.3g} Nm"
            elif hi > 0.25 * _tau_max(ctx)[j]:
                out[j] = f"friction level {hi:.3g} Nm is implausibly large"
        return out

    def apply(self, config, fit):
        # the two levels go into the model's sigmoid, the law's direction-dependent term. A joint without a sigmoid
        # gets one with the fitted levels (F_plus for large positive, -F_minus for large negative velocity) and the
        # fit's width (phi2 = 2 / v_c: the same slope at rest as tanh(dq / v_c)); a joint with one keeps its width
        # phi2 and gets the sum of its levels and the fitted ones (phi1 = L_plus + L_minus, centre phi3 =
        # logit(L_minus / phi1) / phi2), which is exact away from rest (|dq| >> 1 / phi2, v_c).
        c = _joint_coef(fit, 2)
        fr = Friction.from_dict(config.friction.to_dict())
        for j in fit.joints:
            merge = fr.phi1[j] != 0
            if merge:
                p2 = float(fr.phi2[j])
                lp, lm = sigmoid_levels(fr.phi1[j], p2, fr.phi3[j])
                fp, fm = float(lp) + c[j, 0], float(lm) + c[j, 1]
            else:  # the model's Coulomb step (if any) moves into the new sigmoid
                fp, fm = c[j, 0] + fr.coulomb[j], c[j, 1] + fr.coulomb[j]
                p2 = 2.0 / float(fit.theta["coulomb_vel"])
            if fp <= 0 or fm <= 0:
                continue  # a negative level: problems() reports it, nothing is written for this joint
            s0 = fm / (fp + fm)
            fr.phi1[j], fr.phi2[j], fr.phi3[j] = fp + fm, p2, math.log(s0 / (1 - s0)) / p2
            if not merge:
                fr.coulomb[j] = 0.0
        return config.copy(friction=fr)

    injectable = False

    def public(self, fit):
        c = _joint_coef(fit, 2)
        return {"F_plus_Nm": np.round(c[:, 0], 6).tolist(), "F_minus_Nm": np.round(c[:, 1], 6).tolist(),
                "coulomb_vel_rad_per_s": float(fit.theta["coulomb_vel"])}
