"""Designed excitation: the motion to record next, so that the effects in question are identified with narrow
intervals (or told apart).

The motion is a finite Fourier series per joint (Swevers, Ganseman, Tukel, De Schutter and Van Brussel, IEEE Trans.
Robot. Autom. 13(5) 1997; the form of the Gaz et al. 2019 excitation), between rests at its centre pose::

    q_j(t) = c_j + sum_l a_jl sin(w_l s) + b_jl (cos(w_l s) - 1),   w_l = 2 pi l / T_p,   s = t - rest

repeated over whole periods ``T_p``. Two linear conditions per joint fix ``a_j1`` and ``b_j1`` so that velocity and
acceleration are zero where the motion leaves and joins the rests (``sum_l a_jl w_l = 0``, ``sum_l b_jl w_l^2 = 0``):
the robot starts and ends at rest, with a continuous acceleration.

**Criterion.** The workbench's own regressor: a validation :class:`~franka_vs_gym.validation.effects.Context` is
built from the candidate motion (its q, dq, ddq sampled on one period, plus its rest pose; the robot's model), and
each effect in question gives its columns (:meth:`~franka_vs_gym.validation.effects.Effect.design`, friction laws
and the delay's ``-d tau/dt`` included). With white torque noise ``sigma_j`` per joint (the robot's typical floor,
or the noise of a given log) and an effective sample size ``N_eff = duration x neff_rate`` (samples of a 1 kHz robot
log are correlated through the unmodelled part of the residual; ``neff_rate`` 100 Hz by default, i.e. an integrated
autocorrelation time of 10 ms), the parameters' predicted covariance is ``(neff_rate sum_k dt_k x_k W x_k^T)^-1``
and their 95 % interval half-width ``1.96 sqrt(diag)``. The design maximises ``log det`` of the information matrix
normalised by that of a reference motion (D-optimal: small joint confidence region, and effects whose columns are
collinear are pulled apart, which is what ``--separate`` needs) or its smallest eigenvalue (E-optimal: the
worst-identified direction).

**Limits.** Joint positions within the limits minus ``pos_margin``; velocities, accelerations and jerks within
``fraction`` of the robot's limits (``model.limits()``); the flange at least ``clearance`` above the table top
(z = 0 of the base frame) and the end effector and the wrist (joints 5-7) at least ``clearance / 2``, checked
with the model's kinematics. Every candidate is scaled about its centre pose to the largest size within these
limits (linear in the scale for the joint limits, bisection for the clearance), so the optimiser
(``scipy.optimize.minimize``, L-BFGS-B from the best of 8 random starts, within a wall-time budget) only compares
motions the robot may play; the result is re-checked on a 200 Hz grid of the whole motion.

**Scope.** Non-linear shape parameters (smoothing and Stribeck velocities) are held at nominal values; the model's
sigmoid is designed for through its sensitivities to phi1, phi2, phi3. Self-collision and obstacles other than the
table are not checked.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from franka_vs_gym.model.config import ModelConfig

Z95 = 1.959963984540054
NEFF_RATE = 100.0  # Hz: effective independent samples per second of a 1 kHz log (integrated autocorrelation 10 ms)
DESIGN_SAMPLES = 360  # samples of a whole motion (other than a designed one) the criterion is evaluated on
PERIOD_SAMPLES = 120  # samples of one period of a designed motion (its reported widths)
SEARCH_SAMPLES = 48  # samples of one period while searching (8 Hz for a 6 s period: 10 per period of its top
# harmonic, 0.83 Hz)
PERIOD = 6.0  # s, the nominal period of the Fourier series (f0 about 0.17 Hz; 5 harmonics reach 0.83 Hz)


# ---------------------------------------------------------------------------------------------- the motion
@dataclass
class FourierMotion:
    """A rest-to-rest Fourier excitation (see the module docstring). ``centre`` (7,) rad, ``a``, ``b`` (7, L) rad
    (``a[:, 0]`` and ``b[:, 0]`` follow from the others), ``period`` s, ``periods`` whole periods, ``rest`` s at
    each end."""

    centre: np.ndarray
    a: np.ndarray
    b: np.ndarray
    period: float
    periods: int
    rest: float

    @property
    def harmonics(self) -> int:
        return self.a.shape[1]

    @property
    def duration(self) -> float:
        return 2 * self.rest + self.period * self.periods

    @property
    def w(self) -> np.ndarray:
        return 2 * math.pi * np.arange(1, self.harmonics + 1) / self.period

    def constrained(self) -> FourierMotion:
        """The same motion with a[:, 0], b[:, 0] set so that it leaves and joins its rests with zero velocity and
        acceleration."""
        a, b = self.a.copy(), self.b.copy()
        ll = np.arange(1, self.harmonics + 1, dtype=float)
        a[:, 0] = -(a[:, 1:] @ ll[1:])
        b[:, 0] = -(b[:, 1:] @ ll[1:] ** 2)
        return FourierMotion(self.centre.copy(), a, b, self.period, self.periods, self.rest)

    def scaled(self, s: float) -> FourierMotion:
        """Amplitudes scaled by ``s`` about the centre pose (velocity, acceleration and jerk scale by ``s`` too)."""
        return FourierMotion(self.centre.copy(), self.a * s, self.b * s, self.period, self.periods, self.rest)

    def sample(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """q, dq, ddq, dddq (n, 7) at times t (n,) s."""
        t = np.asarray(t, dtype=float)
        s = np.clip(t - self.rest, 0.0, self.period * self.periods)
        moving = ((t > self.rest) & (t < self.rest + self.period * self.periods)).astype(float)[:, None]
        w = self.w
        ph = np.outer(s, w)  # (n, L)
        sn, cs = np.sin(ph), np.cos(ph)
        q = self.centre + sn @ self.a.T + (cs - 1.0) @ self.b.T
        dq = (cs * w) @ self.a.T - (sn * w) @ self.b.T
        ddq = -(sn * w ** 2) @ self.a.T - (cs * w ** 2) @ self.b.T
        dddq = (-(cs * w ** 3) @ self.a.T + (sn * w ** 3) @ self.b.T) * moving
        return q, dq * moving, ddq * moving, dddq

    @staticmethod
    def from_dict(d: dict[str, Any]) -> FourierMotion:
        """The motion of :meth:`to_dict` (the ``motion`` of ``excite.json``)."""
        return FourierMotion(np.asarray(d["centre_rad"], dtype=float), np.asarray(d["a_rad"], dtype=float),
                             np.asarray(d["b_rad"], dtype=float), float(d["period_s"]), int(d["periods"]),
                             float(d["rest_s"]))

    def to_dict(self) -> dict[str, Any]:
        return {"form": "q_j(t) = centre_j + sum_l a_jl sin(w_l s) + b_jl (cos(w_l s) - 1), "
                        "w_l = 2 pi l / period, s = clip(t - rest, 0, periods x period)",
                "centre_rad": self.centre.tolist(), "a_rad": self.a.tolist(), "b_rad": self.b.tolist(),
                "period_s": self.period, "periods": self.periods, "rest_s": self.rest, "duration_s": self.duration}


class SampledMotion:
    """Any motion given as a function t -> (q, dq, ddq) (e.g. the generic excitation of the generators), with
    a ``duration``."""

    def __init__(self, fn, duration: float) -> None:
        self.fn, self.duration = fn, float(duration)

    def sample(self, t: np.ndarray):
        rows = [self.fn(float(x)) for x in np.asarray(t, dtype=float)]
        q, dq, ddq = (np.array([r[i] for r in rows]) for i in range(3))
        return q, dq, ddq, np.gradient(ddq, np.asarray(t, dtype=float), axis=0)


def generic_motion(duration: float, seed: int = 0) -> SampledMotion:
    """The workbench's generic excitation of the same duration: the random Fourier motion of the hidden-effect
    generators (:func:`~franka_vs_gym.validation.hidden.fourier_trajectory`, f0 0.1 Hz, 5 harmonics, peak speed
    about 0.9 rad/s)."""
    from franka_vs_gym.validation.hidden import fourier_trajectory

    return SampledMotion(fourier_trajectory(np.random.default_rng(seed), duration), duration)


def generic_playable(like: FourierMotion, config: ModelConfig | None = None, seed: int = 1, v_peak: float = 0.9,
                     room: float = 0.8, fraction: float = 0.5, pos_margin: float = 0.2,
                     clearance: float = 0.15) -> FourierMotion:
    """The generic excitation as a motion the robot can play: rest to rest with ``like``'s period, periods and rests,
    the generators' centre pose (the neutral pose +- 0.3 rad per joint) and random Fourier coefficients with their
    1/l roll-off (:func:`~franka_vs_gym.validation.hidden.fourier_trajectory`), each joint scaled to a peak speed
    of ``v_peak`` rad/s and at most ``room`` rad from the centre, then shrunk as a whole into the same limits and
    table clearance as a design (:func:`max_scale`). Play it next to a designed motion of the same duration (through
    ``franka-vs serve`` or on the robot) to see what the design gains in fitted intervals, not only predicted ones."""
    from franka_vs_gym.model.franka_model import FrankaModel

    cfg = config if config is not None else ModelConfig()
    model = FrankaModel(cfg)
    rng = np.random.default_rng(seed)
    ll = np.arange(1, like.harmonics + 1)
    lim = Limits.of(model, fraction, pos_margin, clearance)
    centre = np.clip(cfg.robot.neutral() + rng.uniform(-0.3, 0.3, 7), lim.q_min + 0.3, lim.q_max - 0.3)
    m = FourierMotion(centre, rng.normal(0, 1, (7, like.harmonics)) / ll,
                      rng.normal(0, 1, (7, like.harmonics)) / ll, like.period, like.periods, like.rest).constrained()
    t = like.rest + np.linspace(0.0, like.period, 400, endpoint=False)
    q, dq, _, _ = m.sample(t)
    s = np.minimum(v_peak / np.abs(dq).max(axis=0), room / np.abs(q - m.centre).max(axis=0))
    m = FourierMotion(m.centre, m.a * s[:, None], m.b * s[:, None], m.period, m.periods, m.rest)
    t_check = np.linspace(0.0, m.duration, int(m.duration * 200) + 1)
    f = max_scale(m, lim, Kinematics(model), t_check, t_check[::8])
    if f <= 0.0:
        raise ValueError("the centre pose is not within the limits and clear of the table: no generic motion about it")
    return m.scaled(0.999 * f) if f < 1.0 else m


# ---------------------------------------------------------------------------------------------- information
_PLANNED_LOG: list[Any] = []  # the one metadata-only log object of planned motions (built once)


def _processed(time_s: np.ndarray, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray, noise: np.ndarray):
    """A ProcessedLog of a planned motion (the measured torque set to zero: only the regressors are used)."""
    from dataclasses import replace

    from franka_vs_gym.validation.logs import MeasurementLog
    from franka_vs_gym.validation.signals import CleaningReport, CleanSettings, ProcessedLog

    n = len(time_s)
    dt = float(time_s[1] - time_s[0])
    rate = 1.0 / dt
    zeros = np.zeros((n, 7))
    if not _PLANNED_LOG:  # metadata only (tool, gravity: the defaults; the model's are the configuration's)
        from franka_vs_gym.model.description import FER

        q0 = np.repeat(np.asarray(FER.neutral(), dtype=float)[None], 2, axis=0)  # a pose inside every joint range
        _PLANNED_LOG.append(MeasurementLog(np.array([0.0, 0.001]), q0, np.zeros((2, 7)), np.zeros((2, 7)),
                                           extra={"planned": True}))
    settings = replace(CleanSettings(), rate=rate, cutoff=min(10.0, 0.45 * rate), max_gap=4 * dt)
    report = CleaningReport(n, 0, 0, dt, dt, dt, n, {}, [])
    return ProcessedLog(time_s - time_s[0], q, dq, ddq, zeros, zeros, {}, np.asarray(noise, float),
                        _PLANNED_LOG[0], report, settings)


def nominal_shape(effect, ctx) -> dict[str, Any]:
    """The shape (non-linear parameters) an effect's columns are designed with: the model's own values where the
    model has the term, else the values the generators inject (a planned motion has no residual to choose them on).
    """
    from franka_vs_gym.validation.effects.friction import CoulombFriction, StribeckFriction

    fr = ctx.config.friction
    vc = fr.coulomb_vel if fr.coulomb.any() else CoulombFriction.VC
    defaults = {"coulomb_vel": vc, "v_s": (fr.stribeck_vel.tolist() if fr.stribeck.any() else StribeckFriction.VS),
                "phi2": fr.phi2.copy() if fr.phi1.any() else np.full(7, 20.0),
                "phi3": fr.phi3.copy() if fr.phi1.any() else np.zeros(7)}
    probe = effect.shape(ctx, np.zeros((ctx.n, 7)))
    return {k: defaults.get(k, v) for k, v in probe.items()}


@dataclass
class Columns:
    """The stacked, noise-weighted regressor of the effects in question on one motion: ``A`` (n, 7, P) Nm per unit
    parameter divided by the joint's noise, ``names`` (P,), ``owner`` (P,) the effect of each parameter."""

    A: np.ndarray
    names: list[str]
    owner: list[str]

    def information(self) -> np.ndarray:
        return np.einsum("njp,njq->pq", self.A, self.A)


PAYLOAD_NAMES = ("m_kg", "m*c_x_kgm", "m*c_y_kgm", "m*c_z_kgm", "Ixx_kgm2", "Ixy_kgm2", "Iyy_kgm2", "Ixz_kgm2",
                 "Iyz_kgm2", "Izz_kgm2")


def _param_names(effect, p: int) -> list[str]:
    if effect.name == "payload":
        return list(PAYLOAD_NAMES)
    if effect.name == "gravity_tilt":
        return ["dg_x", "dg_y", "dg_z"]
    if effect.name == "delay":
        return ["delay_s"]
    return [f"c{k}" for k in range(p)]


def _sigmoid_jacobian(ctx) -> tuple[np.ndarray, list[str]]:
    """The sigmoid law's sensitivity to its three parameters at the model's values (central differences): the
    re-identification of the model's sigmoid (``fit``'s replacement form) linearised. (The additive design of
    ``SigmoidFriction`` at the model's own shape repeats the model's column, which says nothing of phi2 and phi3.)"""
    from franka_vs_gym.model.friction import gaz_sigmoid

    fr = ctx.config.friction
    p = [np.asarray(fr.phi1, float), np.asarray(fr.phi2, float), np.asarray(fr.phi3, float)]
    if not p[0].any():  # no sigmoid in the model: the one the generators inject
        from franka_vs_gym.model.config import Friction

        base = Friction()
        p = [np.asarray(base.phi1, float), np.asarray(base.phi2, float), np.asarray(base.phi3, float)]
    steps = (1e-3, 1e-3 * np.maximum(p[1], 1.0), 1e-4)
    cols = []
    for k in range(3):
        hi, lo = [x.copy() for x in p], [x.copy() for x in p]
        hi[k] = hi[k] + steps[k]
        lo[k] = lo[k] - steps[k]
        cols.append((gaz_sigmoid(ctx.data.dq, *hi) - gaz_sigmoid(ctx.data.dq, *lo)) / (2 * np.asarray(steps[k])))
    return np.stack(cols, axis=2), ["phi1_Nm", "phi2_s_per_rad", "phi3_rad_per_s"]


def columns(ctx, effects: list, noise: np.ndarray) -> Columns:
    """The effects' design columns on a context, per-joint effects spread to one parameter per joint and column."""
    n = ctx.n
    blocks, names, owner = [], [], []
    w = 1.0 / np.maximum(np.asarray(noise, float), 1e-6)
    for e in effects:
        if e.name == "sigmoid_friction":
            D, base = _sigmoid_jacobian(ctx)
        else:
            D = e.design(ctx, nominal_shape(e, ctx))  # (n, 7, p)
            base = _param_names(e, D.shape[2])
        p = D.shape[2]
        if e.per_joint:
            for j in range(7):
                blk = np.zeros((n, 7, p))
                blk[:, j, :] = D[:, j, :]
                blocks.append(blk)
                names += [f"{e.name}.{nm}[{j}]" if p > 1 else f"{e.name}[{j}]" for nm in base]
                owner += [e.name] * p
        else:
            blocks.append(D)
            names += [f"{e.name}.{nm}" for nm in base]
            owner += [e.name] * p
    A = np.concatenate(blocks, axis=2) * w[None, :, None]
    return Columns(A, names, owner)


def motion_context(motion, config: ModelConfig, noise: np.ndarray, samples: int = DESIGN_SAMPLES):
    """A validation Context of a planned motion sampled at ``samples`` points over its duration."""
    from franka_vs_gym.validation.effects import Context

    t = np.linspace(0.0, motion.duration, samples)
    q, dq, ddq, _ = motion.sample(t)
    return Context(_processed(t, q, dq, ddq, noise), config)


_REST_CACHE: dict[str, Any] = {}  # the rest pose's information while a search varies only the amplitudes


def motion_information(motion, config: ModelConfig, effects: list, noise: np.ndarray,
                       samples: int = PERIOD_SAMPLES) -> tuple[np.ndarray, Columns]:
    """Information per second of motion, ``sum_k dt_k x_k x_k^T`` over the whole motion (P, P), of the effects'
    noise-weighted columns. A FourierMotion is evaluated on one period (``samples`` points; its periods repeat) plus
    its rest pose (weighted by the rests' duration); any other motion on ``samples`` points over its duration."""
    from franka_vs_gym.validation.effects import Context

    if isinstance(motion, FourierMotion):
        t = motion.rest + np.arange(samples) * motion.period / samples
        q, dq, ddq, _ = motion.sample(t)
        cols = columns(Context(_processed(t, q, dq, ddq, noise), config), effects, noise)
        F = cols.information() * (motion.period / samples) * motion.periods
        if motion.rest > 0:
            key = (tuple(e.name for e in effects), np.asarray(noise, float).tobytes(), motion.centre.tobytes())
            if _REST_CACHE.get("key") != key or _REST_CACHE.get("config") is not config:
                qr = np.repeat(motion.centre[None], 2, axis=0)
                tr = np.array([0.0, motion.rest])
                rest = columns(Context(_processed(tr, qr, 0 * qr, 0 * qr, noise), config), effects, noise)
                _REST_CACHE.update(key=key, config=config, info=rest.information())
            F = F + _REST_CACHE["info"] * motion.rest  # two samples, 2 rest in total
        return F, cols
    t = np.linspace(0.0, motion.duration, samples)
    q, dq, ddq, _ = motion.sample(t)
    cols = columns(Context(_processed(t, q, dq, ddq, noise), config), effects, noise)
    return cols.information() * (motion.duration / samples), cols


def log_information(data, config: ModelConfig, effects: list, noise: np.ndarray,
                    max_samples: int = 2000) -> tuple[np.ndarray, Columns]:
    """Information per second (as :func:`motion_information`) of a recorded, processed log."""
    from franka_vs_gym.validation.effects import Context
    from franka_vs_gym.validation.signals import decimated

    sub = decimated(data, max_samples=max_samples)
    if sub.n > max_samples:  # decimation stops above 4x the cutoff: take every k-th sample
        k = -(-sub.n // max_samples)
        sub = sub.subset(np.arange(0, sub.n, k))
    cols = columns(Context(sub, config), effects, noise)
    return cols.information() * (float(sub.time[-1] - sub.time[0]) / sub.n), cols


def predicted_widths(info: np.ndarray, neff_rate: float) -> np.ndarray:
    """95 % interval widths (P,) of the parameters from the information per second of a motion (summed over its
    duration) with ``neff_rate`` effective samples per second (inf where unidentifiable)."""
    F = info * neff_rate
    d = np.sqrt(np.maximum(np.diag(F), 1e-300))
    Fn = F / np.outer(d, d)
    w, V = np.linalg.eigh(Fn)
    good = w > 1e-10 * max(w.max(), 1e-300)
    cov_n = (V[:, good] / w[good]) @ V[:, good].T
    var = np.diag(cov_n) / d ** 2
    out = 2 * Z95 * np.sqrt(np.maximum(var, 0.0))
    # a direction the data cannot see: infinite width for the parameters it involves
    if (~good).any():
        null = np.abs(V[:, ~good]).max(axis=1) > 1e-3
        out[null] = np.inf
    return out


# ---------------------------------------------------------------------------------------------- limits
@dataclass
class Limits:
    q_min: np.ndarray
    q_max: np.ndarray
    dq_max: np.ndarray
    ddq_max: np.ndarray
    dddq_max: np.ndarray
    clearance: float

    @staticmethod
    def of(model, fraction: float, pos_margin: float, clearance: float) -> Limits:
        lim = model.limits()
        return Limits(lim["q_min"] + pos_margin, lim["q_max"] - pos_margin, fraction * lim["dq_max"],
                      fraction * lim["ddq_max"], fraction * lim["dddq_max"], clearance)


class Kinematics:
    """Heights over the table (base z) of the flange, the end effector and the wrist joints, from the model."""

    def __init__(self, model) -> None:
        import pinocchio as pin

        self.pin, self.model = pin, model
        self.m, self.d = model.model, model.model.createData()
        self.frames = (model._fl_id, model._e_id)

    def heights(self, q: np.ndarray) -> np.ndarray:
        """(n, 5) z of flange, end effector, joints 5, 6, 7."""
        pin, m, d = self.pin, self.m, self.d
        out = np.empty((len(q), 5))
        for k, qk in enumerate(q):
            pin.framesForwardKinematics(m, d, qk)
            out[k, 0] = d.oMf[self.frames[0]].translation[2]
            out[k, 1] = d.oMf[self.frames[1]].translation[2]
            for i, jid in enumerate((5, 6, 7)):
                out[k, 2 + i] = d.oMi[jid].translation[2]
        return out


def max_scale(motion: FourierMotion, lim: Limits, kin: Kinematics, t: np.ndarray, t_kin: np.ndarray) -> float:
    """The largest factor on the motion's amplitudes (about its centre pose) that keeps it within the limits on the
    grids ``t`` (positions, velocities, accelerations, jerks: linear in the factor) and ``t_kin`` (table clearance:
    bisection); 0 when the centre pose itself is not clear of the table."""
    q, dq, ddq, dddq = motion.sample(t)
    e = q - motion.centre
    room_up, room_dn = lim.q_max - motion.centre, motion.centre - lim.q_min
    if (room_up <= 0).any() or (room_dn <= 0).any():
        return 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        cands = [np.where(e > 1e-12, room_up / e, np.inf).min(), np.where(e < -1e-12, -room_dn / e, np.inf).min(),
                 (lim.dq_max / np.abs(dq).max(axis=0)).min(), (lim.ddq_max / np.abs(ddq).max(axis=0)).min(),
                 (lim.dddq_max / np.abs(dddq).max(axis=0)).min()]
    s = float(min(cands))
    if not np.isfinite(s):
        s = 1.0
    if lim.clearance <= 0:
        return s
    need = np.array([1.0, 0.5, 0.5, 0.5, 0.5]) * lim.clearance

    def clear(f: float) -> bool:
        qk, _, _, _ = motion.scaled(f).sample(t_kin)
        return bool((kin.heights(qk) >= need).all())

    if clear(s):
        return s
    if not clear(0.0):
        return 0.0
    lo, hi = 0.0, s
    for _ in range(7):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if clear(mid) else (lo, mid)
    return lo


class _OutOfTime(Exception):
    pass


# ---------------------------------------------------------------------------------------------- design
@dataclass
class Design:
    """An excitation design: the motion, what it was designed for, the predicted 95 % widths of the designed motion
    and of the reference, and the optimiser's record."""

    motion: FourierMotion
    effects: list[str]
    separate: list[list[str]]
    criterion: str
    names: list[str]
    owner: list[str]
    widths: np.ndarray
    widths_reference: np.ndarray
    reference: str
    noise: np.ndarray
    neff_rate: float
    seconds: float
    evaluations: int
    collinearity: dict[str, dict[str, float]] = field(default_factory=dict)
    limits: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> list[dict[str, Any]]:
        """Per effect: the median over its parameters of the width ratio reference / designed."""
        out = []
        for e in self.effects:
            idx = [i for i, o in enumerate(self.owner) if o == e]
            wd, wr = self.widths[idx], self.widths_reference[idx]
            fin = np.isfinite(wd) & np.isfinite(wr) & (wd > 0)
            ratio = float(np.median(wr[fin] / wd[fin])) if fin.any() else float("nan")
            out.append({"effect": e, "parameters": len(idx), "median_width_ratio_reference_over_designed": ratio,
                        "unidentified_reference": int(np.sum(~np.isfinite(wr))),
                        "unidentified_designed": int(np.sum(~np.isfinite(wd)))})
        return out

    def to_dict(self) -> dict[str, Any]:
        def num(x):
            return None if not np.isfinite(x) else float(f"{x:.6g}")

        return {"effects": self.effects, "separate": self.separate, "criterion": self.criterion,
                "noise_model": f"white torque noise {np.round(self.noise, 3).tolist()} Nm per joint, effective sample "
                               f"size duration x {self.neff_rate:g} Hz",
                "reference": self.reference,
                "predicted_ci95_width": {n: {"designed": num(a), "reference": num(b)}
                                         for n, a, b in zip(self.names, self.widths, self.widths_reference,
                                                            strict=True)},
                "summary": self.summary(), "collinearity": self.collinearity, "limits": self.limits,
                "motion": self.motion.to_dict(), "design_seconds": round(self.seconds, 2),
                "criterion_evaluations": self.evaluations}


def _collinearity(cols: Columns, groups: list[list[str]]) -> dict[str, float]:
    """For each pair of effects to separate: the cosine of the smallest principal angle between their
    (noise-weighted) column spaces (1: indistinguishable, 0: orthogonal)."""
    from scipy.linalg import subspace_angles

    out = {}
    A = cols.A.reshape(-1, cols.A.shape[2])
    for g in groups:
        for i in range(len(g)):
            for k in range(i + 1, len(g)):
                ia = [p for p, o in enumerate(cols.owner) if o == g[i]]
                ib = [p for p, o in enumerate(cols.owner) if o == g[k]]
                ang = subspace_angles(A[:, ia], A[:, ib])
                out[f"{g[i]}|{g[k]}"] = float(np.cos(ang.min()))
    return out


def design_excitation(effects: list[str], *, separate: list[list[str]] | None = None, duration: float = 30.0,
                      config: ModelConfig | None = None, criterion: str = "D", harmonics: int = 5,
                      rest: float = 1.0, fraction: float = 0.5, pos_margin: float = 0.2, clearance: float = 0.15,
                      noise: Any = None, neff_rate: float = NEFF_RATE, reference: Any = None, seed: int = 0,
                      time_budget: float = 45.0, max_evaluations: int | None = None,
                      verbose: bool = False) -> Design:
    """Design an excitation for ``effects`` (names; those of the ``separate`` groups are added). ``reference`` is a
    ProcessedLog (the log that raised the question) or None (the generic excitation of the same duration). The
    search stops after ``time_budget`` s of wall time or ``max_evaluations`` criterion evaluations, whichever comes
    first (a number of evaluations makes the design the same on any machine). Raises ValueError naming a bad
    input."""
    from scipy.optimize import minimize

    from franka_vs_gym.model.franka_model import FrankaModel
    from franka_vs_gym.validation.compare import progress
    from franka_vs_gym.validation.effects import get_effect
    from franka_vs_gym.validation.hidden import TORQUE_NOISE

    t0 = time.perf_counter()
    separate = [list(g) for g in (separate or [])]
    names: list[str] = []
    for n in list(effects) + [x for g in separate for x in g]:
        e = get_effect(n)
        if e.name not in names:
            names.append(e.name)
    if not names:
        raise ValueError("name at least one effect to design the excitation for")
    for g in separate:
        if len(g) < 2:
            raise ValueError(f"--separate needs two or more effects, got {g}")
    separate = [[get_effect(n).name for n in g] for g in separate]
    if criterion not in ("D", "E"):
        raise ValueError(f"criterion must be 'D' or 'E', got {criterion!r}")
    if not duration >= 2 * rest + 4.0:
        raise ValueError(f"duration {duration:g} s leaves less than 4 s of motion between the {rest:g} s rests")
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction of the limits must be in (0, 1], got {fraction}")
    if harmonics < 2:
        raise ValueError(f"harmonics must be >= 2, got {harmonics}")
    cfg = config if config is not None else ModelConfig()
    model = FrankaModel(cfg)
    effs = [get_effect(n) for n in names]
    sig = np.asarray(TORQUE_NOISE if noise is None else noise, dtype=float)
    lim = Limits.of(model, fraction, pos_margin, clearance)
    kin = Kinematics(model)

    moving = duration - 2 * rest
    periods = max(1, int(round(moving / PERIOD)))
    period = moving / periods

    # the reference: the log that raised the question, or the generic excitation of the same duration
    progress("evaluating the reference motion", verbose)
    if reference is None:
        F_ref, ref_cols = motion_information(generic_motion(duration, seed), cfg, effs, sig, DESIGN_SAMPLES)
        ref_what = f"generic excitation of {duration:g} s (the generators' random Fourier motion, seed {seed})"
    else:
        sig = np.asarray(reference.noise if noise is None else noise, dtype=float)
        F_ref, ref_cols = log_information(reference, cfg, effs, sig)
        ref_what = (f"the log {reference.log.source or '(in memory)'} "
                    f"({float(reference.time[-1] - reference.time[0]):.1f} s)")
    rng = np.random.default_rng(seed)
    L = harmonics
    lo, hi = lim.q_min, lim.q_max
    neutral = cfg.robot.neutral()
    t_lin = rest + np.linspace(0.0, period, int(period * 200), endpoint=False)
    t_kin = np.concatenate([[0.0], rest + np.linspace(0.0, period, 30, endpoint=False)])
    d_ref = np.sqrt(np.maximum(np.diag(F_ref), 1e-12 * max(float(np.diag(F_ref).max()), 1e-300)))

    def unpack(x: np.ndarray) -> FourierMotion:
        a = np.zeros((7, L))
        b = np.zeros((7, L))
        k = 7
        a[:, 1:] = x[k:k + 7 * (L - 1)].reshape(7, L - 1)
        k += 7 * (L - 1)
        b[:, 1:] = x[k:k + 7 * (L - 1)].reshape(7, L - 1)
        return FourierMotion(np.clip(x[:7], lo + 1e-3, hi - 1e-3), a, b, period, periods, rest).constrained()

    def within(m: FourierMotion) -> FourierMotion | None:
        f = max_scale(m, lim, kin, t_lin, t_kin)
        return m.scaled(0.999 * f) if f > 0 else None

    def crit(F: np.ndarray) -> float:
        Fn = F / np.outer(d_ref, d_ref)
        w = np.maximum(np.linalg.eigvalsh(0.5 * (Fn + Fn.T)), 1e-12)
        return -float(np.mean(np.log(w))) if criterion == "D" else -float(np.log(w[0]))

    n_eval = [0]
    best: dict[str, Any] = {"f": np.inf, "m": None}
    deadline = t0 + time_budget

    def objective(x: np.ndarray) -> float:
        if best["m"] is not None and (time.perf_counter() > deadline
                                      or (max_evaluations is not None and n_eval[0] >= max_evaluations)):
            raise _OutOfTime
        n_eval[0] += 1
        m = within(unpack(x))
        if m is None:
            return 1e3
        f = crit(motion_information(m, cfg, effs, sig, SEARCH_SAMPLES)[0])
        if f < best["f"]:
            best["f"], best["m"] = f, m
        return f

    # starting points: random harmonics (amplitudes falling as 1/l) about centres near the neutral pose, each
    # scaled to the limits; the best one is refined
    progress(f"designing a {duration:g} s excitation for {', '.join(names)} ({criterion}-optimal)", verbose)
    starts = []
    for _ in range(8):
        c = np.clip(neutral + rng.uniform(-0.4, 0.4, 7), lo + 0.3, hi - 0.3)
        amp = rng.normal(0, 1, (2, 7, L - 1)) / np.arange(2, L + 1)
        starts.append(np.concatenate([c, amp[0].ravel(), amp[1].ravel()]))
    try:
        fs = [objective(x) for x in starts]
        x0 = starts[int(np.argmin(fs))]
        bound = [(float(a), float(b)) for a, b in zip(lo, hi, strict=True)] + [(-2.0, 2.0)] * (14 * (L - 1))
        minimize(objective, x0, method="L-BFGS-B", bounds=bound, options={"maxiter": 500, "eps": 1e-5})
    except _OutOfTime:
        pass
    motion = best["m"]
    if motion is None:
        raise ValueError("no motion within the limits was found: lower --clearance or the position margin")
    # the result within every limit on a fine grid over the whole motion (200 Hz; kinematics at 25 Hz)
    t_check = np.linspace(0.0, duration, int(duration * 200) + 1)
    f = max_scale(motion, lim, kin, t_check, t_check[::8])
    if f < 1.0:
        motion = motion.scaled(0.999 * f)
    F, cols = motion_information(motion, cfg, effs, sig)
    widths = predicted_widths(F, neff_rate)
    widths_ref = predicted_widths(F_ref, neff_rate)
    groups = separate or ([names] if len(names) > 1 else [])
    col = {}
    if groups:
        col = {"designed": _collinearity(cols, groups), "reference": _collinearity(ref_cols, groups)}
    q, dq, ddq, dddq = motion.sample(t_check)
    full = Limits.of(model, 1.0, 0.0, 0.0)
    lims = {"fraction_of_limits": fraction, "position_margin_rad": pos_margin, "table_clearance_m": clearance,
            "peak_dq_over_limit": np.round((np.abs(dq) / full.dq_max).max(axis=0), 3).tolist(),
            "peak_ddq_over_limit": np.round((np.abs(ddq) / full.ddq_max).max(axis=0), 3).tolist(),
            "peak_dddq_over_limit": np.round((np.abs(dddq) / full.dddq_max).max(axis=0), 3).tolist(),
            "lowest_flange_m": round(float(kin.heights(q[::20])[:, 0].min()), 3),
            "lowest_end_effector_m": round(float(kin.heights(q[::20])[:, 1].min()), 3),
            # the robot's own limits the fractions refer to (what a report draws the motion against)
            "robot_limits": {"q_min_rad": full.q_min.tolist(), "q_max_rad": full.q_max.tolist(),
                             "dq_max_rad_per_s": full.dq_max.tolist(), "ddq_max_rad_per_s2": full.ddq_max.tolist(),
                             "dddq_max_rad_per_s3": full.dddq_max.tolist()}}
    seconds = time.perf_counter() - t0
    progress(f"designed in {seconds:.1f} s ({n_eval[0]} criterion evaluations)", verbose)
    return Design(motion, names, separate, criterion, ref_cols.names, ref_cols.owner, widths, widths_ref, ref_what,
                  sig, neff_rate, seconds, n_eval[0], col, lims)


def effect_widths(data, effects: list[str], config: ModelConfig, neff_rate: float = NEFF_RATE,
                  noise: Any = None) -> dict[str, float]:
    """Predicted 95 % widths of the effects' parameters on a recorded (processed) log, with the same noise model as
    the design (noise: the log's floor unless given)."""
    from franka_vs_gym.validation.effects import get_effect

    sig = np.asarray(data.noise if noise is None else noise, dtype=float)
    F, cols = log_information(data, config, [get_effect(n) for n in effects], sig)
    return dict(zip(cols.names, predicted_widths(F, neff_rate).tolist(), strict=True))


# ---------------------------------------------------------------------------------------------- outputs
def trajectory_table(motion: FourierMotion, rate: float = 1000.0) -> np.ndarray:
    """(n, 22) rows time, q_d[0..6], dq_d[0..6], ddq_d[0..6] at ``rate``."""
    t = np.arange(int(round(motion.duration * rate)) + 1) / rate
    q, dq, ddq, _ = motion.sample(t)
    return np.column_stack([t, q, dq, ddq])


def trajectory_csv(motion: FourierMotion, rate: float = 1000.0, table: np.ndarray | None = None) -> str:
    """trajectory.csv's text: the rows of :func:`trajectory_table` (or the given ``table`` of them)."""
    head = ",".join(["time"] + [f"{n}[{j}]" for n in ("q_d", "dq_d", "ddq_d") for j in range(7)])
    rows = (trajectory_table(motion, rate) if table is None else table) + 0.0  # (no negative zeros)
    body = "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows)
    return head + "\n" + body + "\n"


_MOTION_CODE = '''
MOTION = json.loads({motion!r})
CENTRE = np.array(MOTION["centre_rad"])
A, B = np.array(MOTION["a_rad"]), np.array(MOTION["b_rad"])
PERIOD, PERIODS, REST = MOTION["period_s"], MOTION["periods"], MOTION["rest_s"]
DURATION = MOTION["duration_s"]
W = 2 * math.pi * np.arange(1, A.shape[1] + 1) / PERIOD
DQ_MAX = np.array({dq_max!r})  # rad/s, the robot's limits
DDQ_MAX = np.array({ddq_max!r})  # rad/s^2


def excitation(t, acceleration=False):
    """Designed joint positions and velocities (and with ``acceleration`` accelerations) at time t (s)."""
    s = min(max(t - REST, 0.0), PERIOD * PERIODS)
    sn, cs = np.sin(W * s), np.cos(W * s)
    moving = REST < t < REST + PERIOD * PERIODS
    q = CENTRE + A @ sn + B @ (cs - 1.0)
    dq = (A @ (W * cs) - B @ (W * sn)) if moving else np.zeros(7)
    if not acceleration:
        return q, dq
    ddq = -(A @ (W ** 2 * sn) + B @ (W ** 2 * cs)) if moving else np.zeros(7)
    return q, dq, ddq


def approach_time(q_from):
    """Duration of a quintic move to the centre pose at 20 % of the velocity and acceleration limits."""
    d = np.abs(CENTRE - np.asarray(q_from))
    return float(max(1.0, np.max(1.875 * d / (0.2 * DQ_MAX)), np.max(np.sqrt(5.774 * d / (0.2 * DDQ_MAX)))))


def approach(q_from, T, t):
    s = min(max(t / T, 0.0), 1.0)
    return np.asarray(q_from) + (CENTRE - np.asarray(q_from)) * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)


def log_path():
    """A new file next to this script: nothing recorded before is overwritten."""
    base = Path(__file__).resolve().with_name(Path(__file__).stem.replace("play_", "") + "_recorded")
    k = 0
    while True:
        p = base.with_name(base.name + (f"_{{k}}" if k else "") + ".csv")
        if not p.exists() and not p.with_name(p.name + ".json").exists():
            return p
        k += 1
'''

PYLIBFRANKA_SCRIPT = '''"""Play the designed excitation on a Franka robot with pylibfranka (joint position control
through the robot's internal joint impedance controller) and record the robot state for the workbench.

    python {name} ROBOT_ADDRESS

First a smooth move to the excitation's centre pose (20 % of the limits), then the excitation ({duration:.1f} s);
the recorded states of the excitation go to <this script's name without play_>_recorded.csv (+ .json sidecar), a
new file each run. Read it with: franka-vs diagnose FILE; franka-vs fit FILE --add EFFECTS -o model.json.
Designed by franka-vs excite for: {effects}. The same script runs against 'franka-vs serve' and a real robot.
"""
import json
import math
import sys
from pathlib import Path

import numpy as np
import pylibfranka

from franka_vs_gym.validation.readers.robot_states import StateRecorder
{motion_code}

def main():
    if len(sys.argv) != 2:
        sys.exit("usage: python {name} ROBOT_ADDRESS")
    out = log_path()
    robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
    rec = StateRecorder(seconds=DURATION + 2)
    control = robot.start_joint_position_control(pylibfranka.ControllerMode.JointImpedance)
    t, q_start, T_move = 0.0, None, None
    while True:
        state, period = control.readOnce()
        if q_start is None:
            q_start = np.array(state.q_d)
            T_move = approach_time(q_start)
        t += period.to_sec()
        if t <= T_move:
            q = approach(q_start, T_move, t)
        else:
            rec(state)
            q, _ = excitation(t - T_move)
        cmd = pylibfranka.JointPositions(q.tolist())
        cmd.motion_finished = t >= T_move + DURATION
        control.writeOnce(cmd)
        if cmd.motion_finished:
            break
    rec.save(out)
    print(json.dumps({{"log": str(out), "samples": rec.n, "dropped": rec.dropped}}))


if __name__ == "__main__":
    main()
'''

FRANKY_SCRIPT = '''"""Play the designed excitation on a Franka robot with franky and record the robot state.

    python {name} ROBOT_ADDRESS

First a move to the excitation's centre pose (franky's JointMotion), then the excitation ({duration:.1f} s) as a
joint reference read every control cycle by franky's JointImpedanceTrackingMotion: the designed position and
velocity at the robot's own time, and the designed acceleration through the robot model's mass matrix as feed-forward
torque (a JointWaypointMotion would reach each waypoint at zero acceleration: a ripple at the waypoint rate in the
torques, which a lower-rate recording folds into the motion band). The recorded states go to <this script's name
without play_>_recorded.csv (+ .json sidecar), a new file each run. Read it with: franka-vs diagnose FILE;
franka-vs fit FILE --add EFFECTS -o model.json. Designed by franka-vs excite for: {effects}. The same script runs
against 'franka-vs serve' and a real robot.
"""
import json
import math
import sys
from pathlib import Path

import numpy as np
from franky import (JointImpedanceTrackingMotion, JointMotion, JointReference, Measure, RealtimeConfig,
                    RelativeDynamicsFactor, Robot, TorqueReaction, TorqueStopMotion)

from franka_vs_gym.validation.readers.robot_states import StateRecorder
{motion_code}
STIFFNESS = [600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0]  # Nm/rad (the gains of libfranka's joint impedance
DAMPING = [50.0, 50.0, 50.0, 20.0, 20.0, 20.0, 10.0]  # Nm s/rad   example)


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: python {name} ROBOT_ADDRESS")
    out = log_path()
    robot = Robot(sys.argv[1], realtime_config=RealtimeConfig.Ignore)
    robot.relative_dynamics_factor = RelativeDynamicsFactor(0.2, 0.2, 0.2)
    robot.move(JointMotion(CENTRE.tolist()))
    model = robot.model
    motion = JointImpedanceTrackingMotion(stiffness=STIFFNESS, damping=DAMPING)
    rec = StateRecorder(seconds=DURATION + 5)

    def reference(state, t):
        q, dq, ddq = excitation(t, acceleration=True)
        return JointReference(q.tolist(), dq.tolist(), (model.mass(state) @ ddq).tolist())

    def step(state, dt, rel, abs_time, tau):  # every cycle: record, and the reference for the next one
        rec(state)
        motion.set_reference(reference(state, rel.to_sec() + 0.001))

    motion.set_reference(reference(robot.state, 0.0))
    motion.register_callback(step)
    motion.add_reaction(TorqueReaction(Measure.REL_TIME > DURATION, TorqueStopMotion()))  # then brought to rest
    robot.move(motion)
    rec.save(out)
    print(json.dumps({{"log": str(out), "samples": rec.n, "dropped": rec.dropped}}))


if __name__ == "__main__":
    main()
'''


def scripts(design: Design, stem: str = "excitation") -> dict[str, str]:
    """The pylibfranka and franky scripts that play the design (file name -> text)."""
    from franka_vs_gym.model.franka_model import FrankaModel

    lim = FrankaModel().limits()
    motion = json.dumps(design.motion.to_dict())
    code = _MOTION_CODE.format(motion=motion, dq_max=lim["dq_max"].tolist(), ddq_max=lim["ddq_max"].tolist())
    eff = ", ".join(design.effects)
    out = {}
    n1, n2 = f"play_{stem}_pylibfranka.py", f"play_{stem}_franky.py"
    out[n1] = PYLIBFRANKA_SCRIPT.format(name=n1, duration=design.motion.duration, effects=eff, motion_code=code)
    out[n2] = FRANKY_SCRIPT.format(name=n2, duration=design.motion.duration, effects=eff, motion_code=code)
    return out


__all__ = ["Design", "FourierMotion", "design_excitation", "effect_widths", "generic_motion", "generic_playable",
           "predicted_widths", "scripts", "trajectory_csv", "trajectory_table"]
