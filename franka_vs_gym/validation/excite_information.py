"""The information a motion carries about the effects in question: the effects' columns on the motion's samples
(their own ``design``), the information matrix under white torque noise with an effective sample size, and the
predicted 95 % widths (see :mod:`~franka_vs_gym.validation.excite`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.validation.excite_motion import FourierMotion

Z95 = 1.959963984540054
DESIGN_SAMPLES = 360  # samples of a whole motion (other than a designed one) the criterion is evaluated on
PERIOD_SAMPLES = 120  # samples of one period of a designed motion (its reported widths)


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


__all__ = ["Columns", "columns", "log_information", "motion_context", "motion_information", "nominal_shape",
           "predicted_widths"]
