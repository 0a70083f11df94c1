"""The library of candidate physical effects a model may lack, each with its signature, its fit and its application.

Every effect explains part of the inverse-dynamics residual ``r = tau_J - tau_model`` (N, 7) Nm by a contribution
``c(theta)`` (N, 7) Nm, fitted by least squares on a set of samples, checked for physical plausibility, and applied to
a :class:`~franka_vs_gym.model.config.ModelConfig` (so both the pinocchio model and the MuJoCo plant get it).

======================  ==========  =======================================================================
effect                  parameters  signature in the residual
======================  ==========  =======================================================================
``viscous_friction``    7 (joint)   proportional to dq_i: a straight line through 0 in residual-vs-velocity
``coulomb_friction``    7 (joint)   a step of constant height at dq_i = 0 (tanh smoothing, the model's v_c)
``sigmoid_friction``    3/joint     Gaz et al. sigmoid (Stribeck-like rounded step, may be off-centre);
                                    re-identifies the model's sigmoid (replaces it on the joints selected)
``torque_offset``       7 (joint)   a constant per joint (sensor bias)
``armature``            7 (joint)   proportional to ddq_i (reflected rotor inertia)
``payload``             10          pattern of a rigid body at the flange: gravity torque that depends on the
                                    pose of the wrist, plus inertial torques (mass, first moments, inertia)
``gravity_tilt``        3           gravity torque computed with a different gravity vector (non-vertical
                                    mounting): g(q) error on all joints that carry weight
``delay``               1           the measured torque lags the motion: r ~ -d * d(tau_model)/dt
======================  ==========  =======================================================================

Fits are linear least squares (the sigmoid's shape parameters by a grid, its height linearly; the delay through the
first-order expansion, refined by an exact shift in the final fit).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from franka_vs_gym.model.config import Friction, ModelConfig, RigidBody
from franka_vs_gym.model.description import FER
from franka_vs_gym.model.friction import gaz_sigmoid
from franka_vs_gym.model.geometry import combine_inertials, parallel_axis
from franka_vs_gym.validation.evaluate import FLANGE_OFFSET, ModelEvaluation, evaluate, shift, sigmoid_friction
from franka_vs_gym.validation.signals import ProcessedLog

TAU_MAX = FER.limit_arrays()["tau_max"]
SIG_PHI2 = np.geomspace(2.0, 100.0, 12)  # s/rad
SIG_PHI3 = np.array([-0.08, -0.04, 0.0, 0.04, 0.08])  # rad/s
COULOMB_VC = (0.005, 0.01, 0.02, 0.05, 0.1)  # rad/s, Coulomb smoothing velocities tried
MAX_PAYLOAD = 3.5  # kg (FER rated payload 3 kg, plus margin)
MAX_DELAY = 0.1  # s
MAX_TILT = math.radians(30.0)


class Context:
    """What every effect needs: the processed log, the baseline model's evaluation (with regressors), and the
    residual of the baseline. Built once per diagnosis."""

    def __init__(self, data: ProcessedLog, config: ModelConfig) -> None:
        self.data = data
        self.config = config
        self.ev: ModelEvaluation = evaluate(config, data, regressors=True)
        self.residual = data.tau - self.ev.predicted
        self.dpred = np.gradient(self.ev.predicted, data.time, axis=0)
        self.base_sigmoid = sigmoid_friction(config.friction, data.dq)
        self.n = data.n
        # decimated sample set for the sigmoid shape grid (the signals are low-passed far below 1 kHz)
        self.coarse = np.arange(0, self.n, max(1, int(round(data.settings.rate / 250.0))))
        self._sig_basis: np.ndarray | None = None
        self._grams: dict[tuple, np.ndarray] = {}
        # command channel (when the commanded torque is logged): r_cmd = tau_J - g(q) - tau_J_d, which a command
        # delay d turns into ~ -d d(tau_J_d)/dt; both centred per joint (offsets are another effect)
        cmd = data.optional.get("tau_J_d")
        self.cmd_residual = self.dcmd = None
        if cmd is not None:
            from scipy import signal

            sos = signal.butter(data.settings.order, data.settings.cutoff, fs=data.settings.rate, output="sos")
            dcmd = np.gradient(signal.sosfiltfilt(sos, cmd, axis=0), data.time, axis=0)
            r = data.tau - self.ev.gravity - cmd
            self.cmd_residual = r - r.mean(axis=0)
            self.dcmd = dcmd - dcmd.mean(axis=0)

    def gram(self, key: str, X: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """X[idx]^T X[idx] summed over samples and joints, (p, p), cached per effect and sample set."""
        k = (key, len(idx), int(idx[0]), int(idx[-1]), int(idx.sum()))
        A = self._grams.get(k)
        if A is None:
            Xi = X[idx].reshape(-1, X.shape[2])
            A = np.einsum("mp,mq->pq", Xi, Xi)
            self._grams[k] = A
        return A

    def sigmoid_basis(self) -> np.ndarray:
        """(n_grid, n_coarse, 7) sigmoid shapes s(dq) = 1/(1+exp(-phi2 (dq+phi3))) - 1/(1+exp(-phi2 phi3))."""
        if self._sig_basis is None:
            dq = self.data.dq[self.coarse]
            out = []
            for p2 in SIG_PHI2:
                for p3 in SIG_PHI3:
                    out.append(gaz_sigmoid(dq, 1.0, p2, p3))
            self._sig_basis = np.array(out)
        return self._sig_basis


@dataclass
class Fit:
    """Parameters of one fitted effect: ``theta`` (effect-specific arrays), ``joints`` the joints it applies to."""

    effect: str
    theta: dict[str, Any]
    joints: list[int] = field(default_factory=lambda: list(range(7)))


def _lstsq_joints(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Per-column least squares of Y (m, 7) on X (m, 7): theta (7,). Element-wise sums (no BLAS threads)."""
    den = np.einsum("mj,mj->j", X, X)
    num = np.einsum("mj,mj->j", X, Y)
    return np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0)


class Effect:
    """Base class: name, per_joint (independent parameters per joint) and n_params (per joint if per_joint)."""

    name = ""
    per_joint = True
    n_params = 1
    description = ""
    signature = ""

    def fit(self, ctx: Context, y: np.ndarray, idx: np.ndarray) -> Fit:
        raise NotImplementedError

    def contribution(self, ctx: Context, fit: Fit) -> np.ndarray:
        """(N, 7) Nm added to the model's torque by this effect (zero on joints not in ``fit.joints``)."""
        raise NotImplementedError

    def problems(self, ctx: Context, fit: Fit) -> dict[int, str]:
        """Plausibility problems by joint (key -1 for the whole effect); empty when plausible."""
        return {}

    def apply(self, config: ModelConfig, fit: Fit) -> ModelConfig:
        raise NotImplementedError

    def public(self, fit: Fit) -> dict[str, Any]:
        """JSON-able parameters with units in the names."""
        raise NotImplementedError

    def refine(self, ctx: Context, y: np.ndarray, fit: Fit) -> Fit:
        """Optional non-linear refinement on all samples (final fit only)."""
        return fit


class _LinearJointEffect(Effect):
    unit = ""
    key = ""

    def column(self, ctx: Context) -> np.ndarray:  # (N, 7)
        raise NotImplementedError

    def fit(self, ctx, y, idx):
        th = _lstsq_joints(self.column(ctx)[idx], y[idx])
        return Fit(self.name, {self.key: th})

    def contribution(self, ctx, fit):
        th = np.zeros(7)
        th[fit.joints] = fit.theta[self.key][fit.joints]
        return self.column(ctx) * th

    def public(self, fit):
        th = np.zeros(7)
        th[fit.joints] = fit.theta[self.key][fit.joints]
        return {f"{self.key}_{self.unit}": th.round(6).tolist()}


class ViscousFriction(_LinearJointEffect):
    name, key, unit = "viscous_friction", "viscous", "Nms_per_rad"
    description = "viscous joint friction tau_f = F_v dq (added to the model's friction)"
    signature = "residual proportional to the joint velocity: a line through the origin in residual vs dq"

    def column(self, ctx):
        return ctx.data.dq

    def problems(self, ctx, fit):
        tot = ctx.config.friction.viscous + fit.theta["viscous"]
        return {j: f"negative viscous friction {tot[j]:.3g} Nm s/rad" for j in range(7) if tot[j] < 0} | {
            j: f"viscous friction {tot[j]:.3g} Nm s/rad is implausibly large" for j in range(7)
            if tot[j] > 0.2 * TAU_MAX[j]}

    def apply(self, config, fit):
        fr = Friction.from_dict(config.friction.to_dict())
        fr.viscous[fit.joints] += fit.theta["viscous"][fit.joints]
        return config.copy(friction=fr)


class CoulombFriction(_LinearJointEffect):
    name, key, unit = "coulomb_friction", "coulomb", "Nm"
    description = ("Coulomb joint friction tau_f = F_c tanh(dq / v_c); the smoothing velocity v_c (common to all "
                   "joints) is chosen from COULOMB_VC unless the model already has Coulomb friction")
    signature = "a step of constant height where the joint velocity changes sign"

    def _vcs(self, ctx):
        fr = ctx.config.friction
        return [fr.coulomb_vel] if fr.coulomb.any() else list(COULOMB_VC)

    def fit(self, ctx, y, idx):
        best = None
        for vc in self._vcs(ctx):
            X = np.tanh(ctx.data.dq[idx] / vc)
            th = _lstsq_joints(X, y[idx])
            sse = float(np.sum((y[idx] - X * th) ** 2))
            if best is None or sse < best[0]:
                best = (sse, th, vc)
        return Fit(self.name, {"coulomb": best[1], "coulomb_vel": best[2]})

    def contribution(self, ctx, fit):
        th = np.zeros(7)
        th[fit.joints] = fit.theta["coulomb"][fit.joints]
        return np.tanh(ctx.data.dq / fit.theta["coulomb_vel"]) * th

    def public(self, fit):
        return super().public(fit) | {"coulomb_vel_rad_per_s": fit.theta["coulomb_vel"]}

    def problems(self, ctx, fit):
        tot = ctx.config.friction.coulomb + fit.theta["coulomb"]
        return {j: f"negative Coulomb friction {tot[j]:.3g} Nm" for j in range(7) if tot[j] < 0} | {
            j: f"Coulomb friction {tot[j]:.3g} Nm is implausibly large" for j in range(7)
            if tot[j] > 0.25 * TAU_MAX[j]}

    def apply(self, config, fit):
        fr = Friction.from_dict(config.friction.to_dict())
        fr.coulomb[fit.joints] += fit.theta["coulomb"][fit.joints]
        fr.coulomb_vel = float(fit.theta["coulomb_vel"])
        return config.copy(friction=fr)


class TorqueOffset(_LinearJointEffect):
    name, key, unit = "torque_offset", "offset", "Nm"
    description = "constant bias of the joint torque sensors"
    signature = "a constant shift of the residual, independent of motion and pose"

    def column(self, ctx):
        return np.ones((ctx.n, 7))

    def problems(self, ctx, fit):
        tot = ctx.config.torque_offset + fit.theta["offset"]
        return {j: f"offset {tot[j]:.3g} Nm exceeds 20% of the torque limit" for j in range(7)
                if abs(tot[j]) > 0.2 * TAU_MAX[j]}

    def apply(self, config, fit):
        off = config.torque_offset.copy()
        off[fit.joints] += fit.theta["offset"][fit.joints]
        return config.copy(torque_offset=off)


class Armature(_LinearJointEffect):
    name, key, unit = "armature", "armature", "kgm2"
    description = "reflected rotor inertia added to the diagonal of the mass matrix"
    signature = "residual proportional to the joint's own acceleration"

    def column(self, ctx):
        return ctx.data.ddq

    def problems(self, ctx, fit):
        tot = ctx.config.armature + fit.theta["armature"]
        return {j: f"negative armature {tot[j]:.3g} kg m^2" for j in range(7) if tot[j] < 0} | {
            j: f"armature {tot[j]:.3g} kg m^2 is implausibly large" for j in range(7) if tot[j] > 2.0}

    def apply(self, config, fit):
        a = config.armature.copy()
        a[fit.joints] += fit.theta["armature"][fit.joints]
        return config.copy(armature=np.maximum(a, 0.0))


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
        return p[:, 0] * (s - s0), s, s0, u, u0

    f, s, s0, u, u0 = model(p)
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
        fc, sc, s0c, uc, u0c = model(cand)
        ssec = np.sum((y - fc) ** 2, axis=0)
        ok = ssec < sse
        p[ok] = cand[ok]
        lam = np.where(ok, lam * 0.3, lam * 10.0)
        f, s, s0, u, u0 = model(p)
        sse = np.sum((y - f) ** 2, axis=0)
    return p[:, 0], p[:, 1], p[:, 2]


class SigmoidFriction(Effect):
    name = "sigmoid_friction"
    n_params = 3
    description = ("Gaz et al. sigmoid friction phi1/(1+exp(-phi2 (dq+phi3))) - phi1/(1+exp(-phi2 phi3)) "
                   "(a Stribeck-like rounded step), re-identified per joint")
    signature = "a rounded step in residual vs dq whose width is phi2's inverse, possibly off-centre (phi3)"

    def fit(self, ctx, y, idx):
        basis = ctx.sigmoid_basis()  # (g, nc, 7)
        coarse = ctx.coarse
        mask = np.zeros(ctx.n, dtype=bool)
        mask[idx] = True
        sel = mask[coarse]
        target = (y + ctx.base_sigmoid)[coarse][sel]  # (m, 7)
        B = basis[:, sel, :]  # (g, m, 7)
        num = np.einsum("gmj,mj->gj", B, target)
        den = np.einsum("gmj,gmj->gj", B, B) + 1e-12
        gain = np.where(num > 0, num ** 2 / den, -np.inf)  # phi1 > 0 only
        best = np.argmax(gain, axis=0)  # (7,)
        cols = np.arange(7)
        p1 = np.where(np.isfinite(gain[best, cols]), num[best, cols] / den[best, cols], 0.0)
        p2 = SIG_PHI2[best // len(SIG_PHI3)]
        p3 = SIG_PHI3[best % len(SIG_PHI3)]
        p1, p2, p3 = _sigmoid_lm(ctx.data.dq[coarse][sel], target, p1, p2, p3)
        return Fit(self.name, {"phi1": p1, "phi2": p2, "phi3": p3})

    def refine(self, ctx, y, fit):
        from scipy.optimize import least_squares

        th = {k: np.array(v, dtype=float).copy() for k, v in fit.theta.items()}
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

            x0 = [th["phi1"][j], math.log(th["phi2"][j]), th["phi3"][j]]
            try:
                r = least_squares(res, x0, bounds=([0, math.log(0.5), -0.3], [TAU_MAX[j], math.log(400), 0.3]),
                                  max_nfev=60)
                th["phi1"][j], th["phi2"][j], th["phi3"][j] = r.x[0], math.exp(r.x[1]), r.x[2]
            except ValueError:
                pass
        return Fit(self.name, th, fit.joints)

    def contribution(self, ctx, fit):
        fr = ctx.config.friction
        new = Friction(fr.phi1.copy(), fr.phi2.copy(), fr.phi3.copy())
        j = fit.joints
        new.phi1[j], new.phi2[j], new.phi3[j] = (np.asarray(fit.theta[k])[j] for k in ("phi1", "phi2", "phi3"))
        return sigmoid_friction(new, ctx.data.dq) - ctx.base_sigmoid

    def problems(self, ctx, fit):
        p1 = fit.theta["phi1"]
        out = {j: f"sigmoid height phi1 = {p1[j]:.3g} Nm must be > 0" for j in range(7) if p1[j] <= 0}
        out |= {j: f"sigmoid height phi1 = {p1[j]:.3g} Nm is implausibly large" for j in range(7)
                if p1[j] > 0.25 * TAU_MAX[j]}
        return out

    def apply(self, config, fit):
        fr = Friction.from_dict(config.friction.to_dict())
        j = fit.joints
        fr.phi1[j], fr.phi2[j], fr.phi3[j] = (np.asarray(fit.theta[k])[j] for k in ("phi1", "phi2", "phi3"))
        return config.copy(friction=fr)

    def public(self, fit):
        out = {}
        for k, unit in (("phi1", "Nm"), ("phi2", "s_per_rad"), ("phi3", "rad_per_s")):
            v = np.full(7, np.nan)
            v[fit.joints] = np.asarray(fit.theta[k])[fit.joints]
            out[f"{k}_{unit}"] = [None if not np.isfinite(x) else round(float(x), 6) for x in v]
        return out


class _SharedLinearEffect(Effect):
    per_joint = False

    def design(self, ctx: Context) -> np.ndarray:  # (N, 7, p)
        raise NotImplementedError

    def fit(self, ctx, y, idx):
        Xall = self.design(ctx)
        A = ctx.gram(type(self).__name__, Xall, idx)
        X = Xall[idx]
        b = np.einsum("mjp,mj->p", X, y[idx])
        scale = np.sqrt(np.maximum(np.diag(A), 1e-300))
        An = A / np.outer(scale, scale)
        th = np.linalg.solve(An + 1e-10 * np.eye(len(b)), b / scale) / scale
        return Fit(self.name, {"theta": th})

    def contribution(self, ctx, fit):
        return self.design(ctx) @ fit.theta["theta"]


class GravityTilt(_SharedLinearEffect):
    name = "gravity_tilt"
    n_params = 3
    description = "the gravity vector in the base frame differs from the model's (non-vertical mounting)"
    signature = "gravity-torque error on the weight-carrying joints that varies with the pose"

    def design(self, ctx):
        return ctx.ev.G

    def _g(self, ctx, fit):
        return ctx.config.gravity + fit.theta["theta"]

    def _tilt(self, ctx, fit) -> float:
        """Angle (rad) between the fitted and the model's gravity vectors."""
        g0, g = ctx.config.gravity, self._g(ctx, fit)
        return math.acos(max(-1.0, min(1.0, float(g @ g0 / (np.linalg.norm(g) * np.linalg.norm(g0))))))

    def problems(self, ctx, fit):
        g = self._g(ctx, fit)
        out = {}
        ang = self._tilt(ctx, fit)
        if ang > MAX_TILT:
            out[-1] = f"tilt {math.degrees(ang):.1f} deg exceeds {math.degrees(MAX_TILT):.0f} deg"
        if abs(np.linalg.norm(g) - 9.81) > 0.05 * 9.81:
            out[-1] = f"|g| = {np.linalg.norm(g):.3f} m/s^2 is not Earth's gravity"
        return out

    def apply(self, config, fit):
        return config.copy(gravity=config.gravity + fit.theta["theta"])

    def public(self, fit):
        return {"delta_gravity_m_per_s2": np.round(fit.theta["theta"], 6).tolist()}

    def tilt_deg(self, ctx, fit) -> float:
        return math.degrees(self._tilt(ctx, fit))


def _payload_body(th: np.ndarray) -> tuple[RigidBody, list[str]]:
    """Convert pinocchio dynamic parameters (joint-7 frame) to a RigidBody in the flange frame (projected onto
    physically consistent values) and a list of problems."""
    m = float(th[0])
    problems = []
    if m <= 0:
        return RigidBody(), [f"payload mass {m:.3g} kg must be > 0"]
    c7 = th[1:4] / m
    Ixx, Ixy, Iyy, Ixz, Iyz, Izz = th[4:10]
    Io = np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]])
    Ic = Io - parallel_axis(m, c7)
    # project onto a physically consistent inertia: principal moments >= 1e-6 kg m^2 satisfying the triangle
    # inequality (the simulator rejects anything else)
    w, V = np.linalg.eigh(0.5 * (Ic + Ic.T))
    w = np.maximum(w, 1e-6)
    if w[0] + w[1] < 1.001 * w[2]:  # with a margin: the simulator re-checks after its own eigen-decomposition
        lift = 0.5 * (1.001 * w[2] - w[0] - w[1])
        w[0] += lift
        w[1] += lift
    Ic = (V * w) @ V.T
    com = c7 - FLANGE_OFFSET
    if m > MAX_PAYLOAD:
        problems.append(f"payload mass {m:.3g} kg exceeds {MAX_PAYLOAD} kg")
    if np.linalg.norm(com) > 0.3:
        problems.append(f"payload centre of mass {np.linalg.norm(com):.3g} m from the flange (> 0.3 m)")
    return RigidBody(m, com, Ic), problems


class Payload(_SharedLinearEffect):
    name = "payload"
    n_params = 10
    description = "an unknown rigid body held at the flange (mass, centre of mass, inertia)"
    signature = "wrist-pose-dependent gravity torque on joints 1-6 plus inertial torques of a body at the flange"

    def design(self, ctx):
        return ctx.ev.Y_last

    def problems(self, ctx, fit):
        _, pr = _payload_body(fit.theta["theta"])
        return {-1: "; ".join(pr)} if pr else {}

    def apply(self, config, fit):
        body, _ = _payload_body(fit.theta["theta"])
        if body.mass <= 0:
            return config.copy()
        if config.payload is not None and config.payload.mass > 0:
            body = _combine(config.payload, body)
        return config.copy(payload=body)

    def public(self, fit):
        body, _ = _payload_body(fit.theta["theta"])
        return {"mass_kg": round(body.mass, 6), "com_flange_m": np.round(body.com, 6).tolist(),
                "inertia_kgm2": np.round(body.inertia, 6).tolist()}


def _combine(a: RigidBody, b: RigidBody) -> RigidBody:
    return RigidBody(*combine_inertials([(a.mass, a.com, a.inertia), (b.mass, b.com, b.inertia)]))


class Delay(_SharedLinearEffect):
    name = "delay"
    n_params = 1
    description = "the measured torque lags the measured motion by a constant time (s)"
    signature = "residual ~ -delay x time derivative of the predicted torque: largest where torque changes fast"

    def design(self, ctx):
        return -ctx.dpred[:, :, None]

    def refine(self, ctx, y, fit):
        d0 = float(fit.theta["theta"][0])
        if d0 <= 0:
            return fit
        target = y + ctx.ev.predicted
        t = ctx.data.time
        best, best_sse = d0, np.inf
        for d in np.linspace(0.5 * d0, 1.5 * d0, 21):
            sse = float(np.sum((target - shift(ctx.ev.predicted, t, d)) ** 2))
            if sse < best_sse:
                best, best_sse = d, sse
        return Fit(self.name, {"theta": np.array([best])}, fit.joints)

    def contribution(self, ctx, fit):
        d = float(fit.theta["theta"][0])
        return -ctx.dpred * d

    def problems(self, ctx, fit):
        d = float(fit.theta["theta"][0])
        if d < 0:
            return {-1: f"negative delay {d * 1000:.2f} ms (the torque would lead the motion)"}
        if d < 1.5 * ctx.data.dt:
            return {-1: f"delay {d * 1000:.2f} ms is below 1.5 sample periods: within the alignment uncertainty of "
                        "logged signals"}
        if d > MAX_DELAY:
            return {-1: f"delay {d * 1000:.1f} ms exceeds {MAX_DELAY * 1000:.0f} ms"}
        return {}

    def apply(self, config, fit):
        return config.copy(delay=max(0.0, config.delay + float(fit.theta["theta"][0])),
                           delay_channel="measurement")

    def public(self, fit):
        return {"delay_s": round(float(fit.theta["theta"][0]), 6), "channel": "measurement"}


class CommandDelay(Delay):
    """The ``delay`` effect seen on the command channel: torque commands reach the joints late (as FrankaSim's plant
    applies ``ModelConfig.delay``), so the measured torque lags the *commanded* torque, not the motion. Fitted on
    ``tau_J - g(q) - tau_J_d`` (needs the logged ``tau_J_d``)."""

    description = "torque commands reach the joints late: the measured torque lags the commanded torque"
    signature = "tau_J - g(q) - tau_J_d ~ -delay x d(tau_J_d)/dt"

    def design(self, ctx):
        return -ctx.dcmd[:, :, None]

    def refine(self, ctx, y, fit):
        return fit

    def contribution(self, ctx, fit):
        return -ctx.dcmd * float(fit.theta["theta"][0])

    def apply(self, config, fit):
        return config.copy(delay=max(0.0, config.delay + float(fit.theta["theta"][0])),
                           delay_channel="command")

    def public(self, fit):
        return {"delay_s": round(float(fit.theta["theta"][0]), 6), "channel": "command"}


COMMAND_DELAY = CommandDelay()
LIBRARY: dict[str, Effect] = {e.name: e for e in (
    ViscousFriction(), CoulombFriction(), SigmoidFriction(), TorqueOffset(), Armature(), Payload(),
    GravityTilt(), Delay())}
ALIASES = {"gaz_friction": "sigmoid_friction", "stribeck_friction": "sigmoid_friction", "offset": "torque_offset",
           "tilt": "gravity_tilt", "viscous": "viscous_friction", "coulomb": "coulomb_friction"}
FRICTION_EFFECTS = ("viscous_friction", "coulomb_friction", "sigmoid_friction")


def get_effect(name: str) -> Effect:
    """The effect called ``name`` (aliases: gaz_friction/stribeck_friction, offset, tilt, viscous, coulomb)."""
    key = ALIASES.get(name.strip(), name.strip())
    if key not in LIBRARY:
        raise ValueError(f"unknown effect {name!r}: choose from {', '.join(LIBRARY)}")
    return LIBRARY[key]


__all__ = ["ALIASES", "COMMAND_DELAY", "Context", "Effect", "Fit", "FRICTION_EFFECTS", "LIBRARY", "get_effect"]
