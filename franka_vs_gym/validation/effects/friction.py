"""Friction laws: viscous, Coulomb, Gaz's sigmoid, asymmetric, load-dependent and Stribeck friction."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from franka_vs_gym.model.checks import dissipation_grid
from franka_vs_gym.model.config import Friction, ModelConfig
from franka_vs_gym.model.friction import (
    coulomb_friction,
    gaz_sigmoid,
    sigmoid_levels,
    stribeck_friction,
    viscous_friction,
)
from franka_vs_gym.validation.effects.base import (
    COULOMB_VC,
    SIG_PHI2,
    SIG_PHI3,
    STRIBECK_VS,
    Context,
    Effect,
    Fit,
    NotApplicable,
    _joint_coef,
    _lstsq_joints,
    _model_step_levels,
    _tau_max,
    _vc_choice,
)
from franka_vs_gym.validation.effects.constraints import FeasibleSet, per_joint_coef
from franka_vs_gym.validation.evaluate import sigmoid_friction

LEVEL_MARGIN = 1e-3  # Nm: a constrained direction-dependent level stays this far above zero (the model's sigmoid
# writes it as a centre offset logit(L_minus / phi1) / phi2, which a level of exactly zero would send to infinity)


class _DissipativeLinear(Effect):
    """A friction term with one coefficient per joint, added to the model's friction law: :meth:`constrain` keeps the
    law dissipative. The law is linear in the coefficient c, ``tau_f(dq) = base(dq) + c basis(dq)`` with
    ``basis(dq) dq >= 0``, so on the velocities the model checks (:func:`~franka_vs_gym.model.checks.dissipation_grid`)
    dissipativity is ``c >= c_min`` per joint: the least-squares coefficient constrained to it is
    ``max(c, c_min)``."""

    def friction(self, fr: Friction, fit: Fit) -> Friction:
        """The friction law ``fr`` with this fit added (what :meth:`apply` writes)."""
        raise NotImplementedError

    def apply(self, config, fit):
        return config.copy(friction=self.friction(config.friction, fit))

    def _c_min(self, config: ModelConfig, fit: Fit) -> tuple[np.ndarray, np.ndarray] | None:
        """Per joint the smallest coefficient (7,) that keeps ``config``'s friction law plus this term dissipative on
        the checked velocities (-inf: any), and the joints (7,) bool where no coefficient does (the rest of the law
        pushes where this term is ~0); None when the law cannot take the term."""
        try:
            base = self.friction(config.friction, Fit(fit.effect, {**fit.theta, "coef": np.zeros((7, 1))}, fit.joints))
            one = self.friction(config.friction, Fit(fit.effect, {**fit.theta, "coef": np.ones((7, 1))}, fit.joints))
        except NotApplicable:
            return None
        grid = dissipation_grid(config.robot.limits.dq_max, low_speed=True)
        b = base(grid) * grid
        p = one(grid) * grid - b  # >= 0: the term opposes motion
        pos = p > 1e-12
        c_min = np.max(np.where(pos, -b / np.where(pos, p, 1.0), -np.inf), axis=0)
        fin = np.isfinite(c_min)  # -inf: any coefficient keeps that joint's law dissipative
        c_min[fin] += 1e-7 + 1e-6 * np.abs(c_min[fin])  # strictly inside (the check allows -1e-9 W)
        infeasible = np.any(~pos & (b < -1e-9), axis=0)  # the rest of the law pushes where this term is ~0
        return c_min, infeasible

    def feasible_set(self, ctx, fit):
        """The coefficient of each fitted joint bounded below by the dissipative limit (:meth:`_c_min`); a joint no
        coefficient makes dissipative is not bounded here (:meth:`constrain` leaves it out)."""
        lim = self._c_min(ctx.config, fit)
        if lim is None or not fit.joints:
            return None
        c_min, infeasible = lim
        lower = np.where(infeasible, -np.inf, c_min)[fit.joints]
        x0 = _joint_coef(fit)[fit.joints, 0]

        def make(x):
            coef = np.asarray(fit.theta["coef"], dtype=float).reshape(7, -1).copy()
            coef[:, 0] = per_joint_coef(fit, x, 1)[:, 0]
            return Fit(fit.effect, {**fit.theta, "coef": coef}, list(fit.joints))

        return FeasibleSet(np.maximum(x0, lower), lambda x: np.asarray(x, dtype=float), make,
                           bool(np.all(x0 >= lower)), lower=lower)

    def constrain(self, ctx, config, fit):
        c = _joint_coef(fit)[:, 0]
        lim = self._c_min(config, fit)
        if lim is None:
            return fit, None
        c_min, infeasible = lim
        joints, said = [], []
        new = c.copy()
        for j in fit.joints:
            if infeasible[j]:
                said.append(f"joint {j} left out (the rest of its friction law pushes the joint)")
                continue
            joints.append(j)
            if c[j] < c_min[j]:
                new[j] = c_min[j]
                said.append(f"joint {j} constrained to a dissipative law ({c[j]:.3g} -> {new[j]:.3g})")
        if not said:
            return fit, None
        coef = np.asarray(fit.theta["coef"], dtype=float).copy()
        coef.reshape(7, -1)[:, 0] = new
        return Fit(fit.effect, {**fit.theta, "coef": coef}, joints), "; ".join(said)


class ViscousFriction(_DissipativeLinear):
    """Viscous joint friction ``tau_f = F_v dq`` (added to the model's friction).

    Signature: residual proportional to the joint velocity, a straight line through 0 in residual vs dq.
    Plausible: total F_v >= 0 and < 0.2 tau_max Nm s/rad (FER joints: about 0.01-0.7 Nm s/rad identified).
    """

    name, aliases = "viscous_friction", ("viscous",)
    description = "viscous joint friction tau_f = F_v dq (added to the model's friction)"
    signature = "residual proportional to the joint velocity: a line through the origin in residual vs dq"
    plausible = "total F_v >= 0 and < 0.2 tau_max (Nm s/rad)"
    SIZES = np.array([0.5, 0.5, 0.4, 0.4, 0.15, 0.15, 0.08])

    lof_signals = ("dq",)

    def design(self, ctx, shape):
        return viscous_friction(ctx.data.dq, 1.0)[:, :, None]

    def problems(self, ctx, fit):
        tot = ctx.config.friction.viscous + _joint_coef(fit)[:, 0]
        return {j: f"negative viscous friction {tot[j]:.3g} Nm s/rad" for j in fit.joints if tot[j] < 0} | {
            j: f"viscous friction {tot[j]:.3g} Nm s/rad is implausibly large" for j in fit.joints
            if tot[j] > 0.2 * _tau_max(ctx)[j]}

    def friction(self, fr, fit):
        fr = Friction.from_dict(fr.to_dict())
        fr.viscous = fr.viscous + _joint_coef(fit)[:, 0]
        return fr

    def inject(self, plant, rng, magnitude):
        v = self.SIZES * magnitude * rng.uniform(0.7, 1.3, 7)
        fr = Friction.from_dict(plant.config.friction.to_dict())
        fr.viscous = fr.viscous + v
        plant.config = plant.config.copy(friction=fr)
        return {"viscous_Nms_per_rad": v.tolist()}

    def public(self, fit):
        return {"viscous_Nms_per_rad": np.round(_joint_coef(fit)[:, 0], 6).tolist()}


class CoulombFriction(_DissipativeLinear):
    """Coulomb joint friction ``tau_f = F_c tanh(dq / v_c)``; the smoothing velocity v_c (common to all joints) is
    chosen from COULOMB_VC on the residual unless the model already has Coulomb friction.

    Signature: a step of constant height where the joint velocity changes sign.
    Plausible: the total step level in each direction (the model's sigmoid asymptote and Coulomb term plus F_c)
    >= 0, and the total Coulomb term < 0.25 tau_max Nm (FER: 0.1-1.5 Nm).
    """

    name, aliases = "coulomb_friction", ("coulomb",)
    description = "Coulomb joint friction tau_f = F_c tanh(dq / v_c)"
    signature = "a step of constant height where the joint velocity changes sign"
    plausible = "total step level (model + F_c) >= 0 in each direction, total F_c < 0.25 tau_max (Nm)"
    SIZES = np.array([0.8, 0.8, 0.6, 0.6, 0.25, 0.25, 0.15])
    VC = 0.05  # smoothing of injected Coulomb friction (a sharper step chatters in the 1 ms explicit plant)

    lof_constant_height = True
    lof_signals = ("dq",)

    def shape(self, ctx, target):
        return {"coulomb_vel": _vc_choice(ctx, target, lambda dq, vc: coulomb_friction(dq, 1.0, vc))}

    def design(self, ctx, shape):
        vc = float(shape["coulomb_vel"])
        return ctx.cached(("tanh", vc), lambda: coulomb_friction(ctx.data.dq, 1.0, vc)[:, :, None])

    def problems(self, ctx, fit):
        lp, lm = _model_step_levels(ctx)
        c = _joint_coef(fit)[:, 0]
        low = np.minimum(lp, lm) + c  # the total step level (model's sigmoid and Coulomb + this) per direction
        tot = ctx.config.friction.coulomb + c
        return {j: f"negative Coulomb friction: total level {low[j]:.3g} Nm" for j in fit.joints if low[j] < 0} | {
            j: f"Coulomb friction {tot[j]:.3g} Nm is implausibly large" for j in fit.joints
            if tot[j] > 0.25 * _tau_max(ctx)[j]}

    def friction(self, fr, fit):
        fr = Friction.from_dict(fr.to_dict())
        fr.coulomb = fr.coulomb + _joint_coef(fit)[:, 0]
        fr.coulomb_vel = float(fit.theta["coulomb_vel"])
        return fr

    def inject(self, plant, rng, magnitude):
        c = self.SIZES * magnitude * rng.uniform(0.7, 1.3, 7)
        fr = Friction.from_dict(plant.config.friction.to_dict())
        fr.coulomb, fr.coulomb_vel = fr.coulomb + c, self.VC
        plant.config = plant.config.copy(friction=fr)
        return {"coulomb_Nm": c.tolist(), "coulomb_vel_rad_per_s": self.VC}

    def public(self, fit):
        return {"coulomb_Nm": np.round(_joint_coef(fit)[:, 0], 6).tolist(),
                "coulomb_vel_rad_per_s": float(fit.theta["coulomb_vel"])}


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

    def _lower(self, config: ModelConfig) -> np.ndarray:
        """(7, 2) the smallest (F_plus, F_minus) per joint that :meth:`apply` can write: the levels it adds them to
        (the model's sigmoid asymptotes where the joint has a sigmoid, else its Coulomb term) kept positive."""
        fr = config.friction
        out = np.empty((7, 2))
        for j in range(7):
            if fr.phi1[j] != 0:
                lp, lm = sigmoid_levels(fr.phi1[j], float(fr.phi2[j]), fr.phi3[j])
                out[j] = (-float(lp), -float(lm))
            else:
                out[j] = (-float(fr.coulomb[j]), -float(fr.coulomb[j]))
        return out + LEVEL_MARGIN

    def feasible_set(self, ctx, fit):
        """Both levels of each fitted joint bounded below so that the law's total level in each direction stays
        positive (what :meth:`apply` writes into the model's sigmoid)."""
        if not fit.joints:
            return None
        lower = self._lower(ctx.config)[fit.joints].ravel()
        x0 = _joint_coef(fit, 2)[fit.joints].ravel()

        def make(x):
            return Fit(fit.effect, {**fit.theta, "coef": per_joint_coef(fit, x, 2)}, list(fit.joints))

        return FeasibleSet(np.maximum(x0, lower), lambda x: np.asarray(x, dtype=float), make,
                           bool(np.all(x0 >= lower)), lower=lower)

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


class LoadDependentFriction(Effect):
    """Load-dependent Coulomb friction of a strain-wave (harmonic) gear: the friction grows with the torque the
    gear transmits, ``tau_f = mu |tau_load| tanh(dq / v_c)`` with ``tau_load`` the model's rigid-body torque
    (gravity + inertia). Reported for Franka joints by Wolf et al. 2018 and in harmonic-drive models
    (Tjahjowidodo; Taghirad & Belanger 1998).

    Signature: a friction step whose height follows the joint's load (large where gravity loads the joint).
    Plausible: 0 <= total mu < 0.3 (a gear efficiency above about 70%). Diagnose-only: with a load term the
    friction would depend on the inertial torque, i.e. on the acceleration it helps produce, so forward dynamics
    would have to solve an implicit equation at every step; the model's friction law is explicit in dq, so
    ``apply`` raises NotApplicable and ``fit`` says why (:attr:`not_applicable`).
    """

    name, aliases = "load_dependent_friction", ("load_friction",)
    description = "Coulomb friction proportional to the transmitted torque (gear efficiency)"
    signature = "a step at zero velocity whose height grows with abs(load torque)"
    plausible = "0 <= mu < 0.3 (gear efficiency > 70%)"
    injectable = False
    not_applicable = ("its friction grows with the load torque, which depends on the acceleration it produces, so "
                      "the law would be implicit in forward dynamics; the model's friction law depends on dq only")

    def shape(self, ctx, target):
        load = np.abs(ctx.ev.rigid)
        return {"coulomb_vel": _vc_choice(ctx, target, lambda dq, vc: np.tanh(dq / vc) * load[ctx.coarse])}

    def design(self, ctx, shape):
        vc = float(shape["coulomb_vel"])
        return ctx.cached(("load", vc), lambda: (np.abs(ctx.ev.rigid) * np.tanh(ctx.data.dq / vc))[:, :, None])

    def problems(self, ctx, fit):
        mu = _joint_coef(fit)[:, 0]
        return {j: f"negative load coefficient {mu[j]:.3g}" for j in fit.joints if mu[j] < 0} | {
            j: f"load coefficient {mu[j]:.3g} implies a gear efficiency below 70%" for j in fit.joints
            if mu[j] >= 0.3}

    def public(self, fit):
        return {"mu": np.round(_joint_coef(fit)[:, 0], 6).tolist(),
                "coulomb_vel_rad_per_s": float(fit.theta["coulomb_vel"])}


class StribeckFriction(_DissipativeLinear):
    """The Stribeck effect: friction higher at breakaway than in sliding, decaying with speed,
    ``tau_f = F_s exp(-(dq / v_s)^2) tanh(dq / v_c)`` on top of the model's friction (the exponential Stribeck curve
    of Armstrong-Helouvry, Dupont & Canudas de Wit, Automatica 30(7) 1994, its sign smoothed through zero as the
    Coulomb term is; reported for harmonic drives by Tjahjowidodo et al. and for Franka joints by Gaz et al. 2019,
    who found it small). The law is the model's Stribeck term (:func:`franka_vs_gym.model.friction.stribeck_friction`,
    ``stribeck`` = F_s, ``stribeck_vel`` = v_s, smoothing ``coulomb_vel`` = v_c). ``v_s`` (common to all joints) is
    chosen on the residual from STRIBECK_VS with the model's v_c; the final fit (:meth:`refine`) also chooses v_c
    from COULOMB_VC when the model has neither a Stribeck nor a Coulomb term. A model that has a Stribeck term keeps
    its ``stribeck_vel`` (per joint) and ``coulomb_vel``, so that the fitted height adds to the model's.

    Signature: a hump in residual vs dq right after each velocity reversal, vanishing above a few v_s.
    Plausible: 0 <= total F_s < 0.25 tau_max Nm (static friction exceeds sliding friction). ``apply`` writes F_s,
    v_s (and v_c when the model has no Coulomb term) into the model's friction law, so model and plant both get it.
    Not in the hidden-effect generator's random draw (``injectable`` False: the seeds of the existing studies keep
    drawing the same effects); ``make_hidden_effect_log("stribeck_friction")`` injects it.
    """

    name, aliases = "stribeck_friction", ("stribeck_hump",)
    n_params = 1
    description = "Stribeck hump: extra friction near zero velocity, decaying with speed"
    signature = "a hump of friction right after velocity reversals, gone above a few v_s"
    plausible = "0 <= total F_s < 0.25 tau_max (Nm)"
    injectable = False
    SIZES = np.array([0.8, 0.8, 0.6, 0.6, 0.25, 0.25, 0.15])  # Nm, injected heights at magnitude 1
    VS, VC = 0.1, 0.05  # rad/s, injected Stribeck and smoothing velocities (a sharper step chatters at 1 ms)

    lof_constant_height = True
    lof_signals = ("dq",)

    def shape(self, ctx, target):
        fr = ctx.config.friction
        vc = fr.coulomb_vel
        if fr.stribeck.any():
            return {"v_s": fr.stribeck_vel.tolist(), "coulomb_vel": vc}
        return {"v_s": _vc_choice(ctx, target, lambda dq, v: stribeck_friction(dq, 1.0, v, vc), STRIBECK_VS),
                "coulomb_vel": vc}

    def refine(self, ctx, y, fit):
        """With neither a Stribeck nor a Coulomb term in the model, the final fit also chooses the smoothing
        velocity v_c (COULOMB_VC, with v_s > v_c) that the model will get; otherwise the fit is kept."""
        fr = ctx.config.friction
        if fr.stribeck.any() or fr.coulomb.any():
            return fit
        dq, yc = ctx.data.dq[ctx.coarse], y[ctx.coarse]
        best, best_sse = (fit.theta["v_s"], fit.theta["coulomb_vel"]), np.inf
        for vc in COULOMB_VC:
            for vs in STRIBECK_VS:
                if vs <= vc:  # a hump needs v_s above the smoothing of its sign
                    continue
                X = stribeck_friction(dq, 1.0, vs, vc)
                sse = float(np.sum((yc - X * _lstsq_joints(X, yc)) ** 2))
                if sse < best_sse:
                    best, best_sse = (vs, vc), sse
        shape = {"v_s": best[0], "coulomb_vel": best[1]}
        X = self.design(ctx, shape)
        out = self.make_fit(ctx, _lstsq_joints(X[:, :, 0], y)[:, None], shape, fit.joints)
        return out

    def design(self, ctx, shape):
        vs, vc = shape["v_s"], float(shape["coulomb_vel"])
        key = ("stribeck", tuple(np.atleast_1d(np.asarray(vs, dtype=float)).tolist()), vc)
        return ctx.cached(key, lambda: stribeck_friction(ctx.data.dq, 1.0, np.asarray(vs, dtype=float),
                                                         vc)[:, :, None])

    def _total(self, config: ModelConfig, fit: Fit) -> np.ndarray:
        return config.friction.stribeck + _joint_coef(fit)[:, 0]

    def problems(self, ctx, fit):
        c = self._total(ctx.config, fit)
        tm = _tau_max(ctx)
        return {j: f"negative Stribeck height {c[j]:.3g} Nm (friction lower at breakaway)" for j in fit.joints
                if c[j] < 0} | {j: f"Stribeck height {c[j]:.3g} Nm is implausibly large" for j in fit.joints
                                if c[j] >= 0.25 * tm[j]}

    def friction(self, fr, fit):
        fr = Friction.from_dict(fr.to_dict())
        vs = np.broadcast_to(np.asarray(fit.theta["v_s"], dtype=float), (7,))
        c = _joint_coef(fit)[:, 0]
        for j in fit.joints:
            if c[j] == 0.0:
                continue
            if fr.stribeck[j] != 0.0 and fr.stribeck_vel[j] != vs[j]:
                raise NotApplicable(f"stribeck_friction on joint {j}: the model's Stribeck velocity is "
                                    f"{fr.stribeck_vel[j]:g} rad/s, the fit's {vs[j]:g} rad/s")
            fr.stribeck[j] += c[j]
            fr.stribeck_vel[j] = vs[j]
        if not fr.coulomb.any():  # the hump's sign smoothing is the Coulomb term's (kept when the model has one)
            fr.coulomb_vel = float(fit.theta["coulomb_vel"])
        return fr

    def inject(self, plant, rng, magnitude):
        h = self.SIZES * magnitude * rng.uniform(0.7, 1.3, 7)
        fr = Friction.from_dict(plant.config.friction.to_dict())
        if fr.coulomb.any() and fr.coulomb_vel != self.VC:
            raise ValueError("stribeck_friction is injected with the plant's Coulomb smoothing velocity "
                             f"{self.VC} rad/s; the plant's Coulomb term has {fr.coulomb_vel} rad/s")
        fr.stribeck, fr.stribeck_vel, fr.coulomb_vel = fr.stribeck + h, np.full(7, self.VS), self.VC
        plant.config = plant.config.copy(friction=fr)
        return {"F_s_Nm": h.tolist(), "v_s_rad_per_s": self.VS, "coulomb_vel_rad_per_s": self.VC}

    def public(self, fit):
        vs = fit.theta["v_s"]
        return {"F_s_Nm": np.round(_joint_coef(fit)[:, 0], 6).tolist(),
                "v_s_rad_per_s": float(vs) if np.ndim(vs) == 0 else np.round(np.asarray(vs, float), 6).tolist(),
                "coulomb_vel_rad_per_s": float(fit.theta["coulomb_vel"])}


