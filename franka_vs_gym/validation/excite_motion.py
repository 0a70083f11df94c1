"""The excitation's motion: a finite Fourier series per joint between rests (:class:`FourierMotion`), the generic
motions it is compared with, and the limits every candidate is scaled into (joint range, speed, acceleration, jerk,
table clearance; see :mod:`~franka_vs_gym.validation.excite`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from franka_vs_gym.model.config import ModelConfig


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


__all__ = ["FourierMotion", "Kinematics", "Limits", "SampledMotion", "generic_motion", "generic_playable", "max_scale"]
