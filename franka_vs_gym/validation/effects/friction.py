"""Friction laws linear in their coefficients: viscous, Coulomb, load-dependent and Stribeck friction (Gaz's sigmoid
and asymmetric friction: :mod:`.sigmoid`)."""

from __future__ import annotations

import numpy as np

from franka_vs_gym.model.checks import dissipation_grid
from franka_vs_gym.model.config import Friction, ModelConfig
from franka_vs_gym.model.friction import (
    coulomb_friction,
    stribeck_friction,
    viscous_friction,
)
from franka_vs_gym.validation.effects.base import (
    COULOMB_VC,
    STRIBECK_VS,
    Effect,
    Fit,
    NotApplicable,
    _joint_coef,
    _lstsq_joints,
    _model_step_levels,
    _tau_max,
    _vc_choice,
)


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

    def constrain(self, ctx, config, fit):
        c = _joint_coef(fit)[:, 0]
        try:
            base = self.friction(config.friction, Fit(fit.effect, {**fit.theta, "coef": np.zeros((7, 1))}, fit.joints))
            one = self.friction(config.friction, Fit(fit.effect, {**fit.theta, "coef": np.ones((7, 1))}, fit.joints))
        except NotApplicable:
            return fit, None
        grid = dissipation_grid(config.robot.limits.dq_max, low_speed=True)
        b = base(grid) * grid
        p = one(grid) * grid - b  # >= 0: the term opposes motion
        pos = p > 1e-12
        c_min = np.max(np.where(pos, -b / np.where(pos, p, 1.0), -np.inf), axis=0)
        fin = np.isfinite(c_min)  # -inf: any coefficient keeps that joint's law dissipative
        c_min[fin] += 1e-7 + 1e-6 * np.abs(c_min[fin])  # strictly inside (the check allows -1e-9 W)
        infeasible = np.any(~pos & (b < -1e-9), axis=0)  # the rest of the law pushes where this term is ~0
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


