"""A known physical effect added to a *real* recording: the torque the effect would add is computed from the
recording's own motion (its q and dq as logged, and its acceleration from the low-passed velocity) and added to the
measured torque, so the noise, the sampling and the robot's own unmodelled effects stay real.

Library effects inject themselves through their class (:meth:`Effect.inject` changes a plant configuration; the
torque added is the difference of the inverse dynamics of the changed and the untouched configuration on the
recording's motion). They are sized to the recording: per-joint effects act on one joint (drawn), scaled so that the
RMS of what they add is ``factor`` (drawn in [2, 6]) times that joint's noise floor; a payload has 0.3-1.2 kg, a tilt
1-3 degrees, a delay is sized like a per-joint effect on its most affected joint. Effects outside the library:

=============  ===================================================================================================
``cogging``    ``A sin(k q_j + phase)`` on one joint, k 20-60 cycles per turn
``cable``      a cable spring ``-K (q_j - q_ref)`` on joint 0, 5 or 6 (where cables twist)
``crosstalk``  torque-sensor crosstalk: joint j (a wrist joint) measures ``c tau_i`` of a proximal joint i as well
``grasp``      a payload of 0.3-1.2 kg picked up at 35-65 % of the log (a 50 ms ramp)
=============  ===================================================================================================
"""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
from scipy import signal

from franka_vs_gym.model.config import ModelConfig, RigidBody, Tool
from franka_vs_gym.validation.logs import MeasurementLog

LIBRARY_KINDS = ("payload", "tilt", "offset", "viscous", "coulomb", "armature", "delay")
COMPOUND_KINDS = ("payload+viscous", "offset+coulomb")
OUTSIDE_KINDS = ("cogging", "cable", "crosstalk", "grasp")
KINDS = LIBRARY_KINDS + COMPOUND_KINDS + OUTSIDE_KINDS
EFFECT_OF = {"payload": "payload", "tilt": "gravity_tilt", "offset": "torque_offset", "viscous": "viscous_friction",
             "coulomb": "coulomb_friction", "armature": "armature", "delay": "delay"}
PER_JOINT = {"offset", "viscous", "coulomb", "armature"}
FACTOR = (2.0, 6.0)  # injected RMS on a touched joint, in noise floors
PAYLOAD_KG = (0.3, 1.2)
TILT_DEG = (1.0, 3.0)


def distinct_rows(log: MeasurementLog) -> np.ndarray:
    """Indices of the rows with a new time stamp (repeated stamps dropped, as cleaning does)."""
    return np.nonzero(np.r_[True, np.diff(log.time) > 0])[0]


def every_kth(log: MeasurementLog, k: int) -> MeasurementLog:
    """Every k-th distinct row of ``log``, as a lower-rate recording (a ROS topic) of the same motion gives."""
    idx = distinct_rows(log)[::k]
    opt = {n: getattr(log, n)[idx] for n in ("tau_J_d", "q_d", "dq_d", "ddq_d", "tau_ext_hat_filtered")
           if getattr(log, n) is not None}
    return MeasurementLog(log.time[idx], log.q[idx], log.dq[idx], log.tau_J[idx], tool=log.tool, gravity=log.gravity,
                          controller=log.controller, extra=dict(log.extra), source=log.source,
                          tool_declared=log.tool_declared, **opt)


def motion(log: MeasurementLog, cutoff: float = 10.0) -> SimpleNamespace:
    """The recording's motion at its own rows: q and dq as logged, ddq the derivative of the velocity low-passed at
    ``cutoff`` Hz (zero phase, on a uniform 1 kHz grid, interpolated back to the rows)."""
    t = log.time
    grid = np.arange(t[0], t[-1], 1e-3)
    u = np.column_stack([np.interp(grid, t, log.dq[:, j]) for j in range(7)])
    sos = signal.butter(4, cutoff, fs=1000.0, output="sos")
    ddq_g = np.gradient(signal.sosfiltfilt(sos, u, axis=0), 1e-3, axis=0)
    ddq = np.column_stack([np.interp(t, grid, ddq_g[:, j]) for j in range(7)])
    return SimpleNamespace(time=t - t[0], q=log.q, dq=log.dq, ddq=ddq)


def _torque(cfg: ModelConfig, m: SimpleNamespace) -> np.ndarray:
    from franka_vs_gym.validation.evaluate import evaluate

    return evaluate(cfg, m).predicted


def _rms(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(x ** 2, axis=0))


def _library(kind: str, base: ModelConfig, m: SimpleNamespace, tau0: np.ndarray, noise: np.ndarray,
             rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
    """Torque (N, 7) Nm that library effect ``kind`` adds, and its truth."""
    from franka_vs_gym.validation.effects import PlantChange, get_effect

    e = get_effect(EFFECT_OF[kind])
    plant = PlantChange(base.copy())
    drawn = e.inject(plant, rng, 1.0)
    if kind == "payload":
        body = plant.payload
        mass = float(rng.uniform(*PAYLOAD_KG))
        body = RigidBody(mass, np.asarray(body.com), np.asarray(body.inertia) * mass / body.mass)
        tau = _torque(base.copy(payload=body), m) - tau0
        return tau, {"effect": "payload", "mass_kg": mass, "com_flange_m": np.round(body.com, 4).tolist(),
                     "joints": [j for j in range(7) if _rms(tau)[j] >= noise[j]]}
    if kind == "tilt":
        g0, g1 = base.gravity, np.asarray(drawn["gravity_m_per_s2"])
        axis = np.cross(g0, g1)
        axis /= np.linalg.norm(axis)
        ang = math.radians(float(rng.uniform(*TILT_DEG)))
        g = g0 * math.cos(ang) + np.cross(axis, g0) * math.sin(ang) + axis * (axis @ g0) * (1 - math.cos(ang))
        tau = _torque(base.copy(gravity=g), m) - tau0
        return tau, {"effect": "gravity_tilt", "tilt_deg": math.degrees(ang),
                     "delta_gravity_m_per_s2": np.round(g - g0, 5).tolist(),
                     "joints": [j for j in range(7) if _rms(tau)[j] >= noise[j]]}
    if kind == "delay":
        d = float(drawn["delay_s"])
        shifted = np.column_stack([np.interp(m.time - d, m.time, tau0[:, j]) for j in range(7)])
        size = _rms(shifted - tau0) / noise
        scale = float(rng.uniform(*FACTOR)) / float(size.max())
        return np.zeros_like(tau0), {"effect": "delay", "delay_s": d * scale,
                                     "joints": [j for j in range(7) if size[j] * scale >= 1.0]}
    # per-joint effects: one joint, scaled to factor x its noise floor
    tau = _torque(plant.config, m) - tau0
    j = int(rng.integers(0, 7))
    factor = float(rng.uniform(*FACTOR))
    r = float(_rms(tau[:, j:j + 1])[0])
    s = factor * noise[j] / max(r, 1e-12)
    out = np.zeros_like(tau)
    out[:, j] = s * tau[:, j]
    key, val = next(iter(drawn.items()))
    return out, {"effect": e.name, key: float(np.asarray(val)[j]) * s, "joints": [j], "factor": factor}


def _outside(kind: str, base: ModelConfig, m: SimpleNamespace, tau_meas: np.ndarray, noise: np.ndarray,
             rng: np.random.Generator) -> tuple[np.ndarray, dict[str, Any]]:
    factor = float(rng.uniform(*FACTOR))
    out = np.zeros_like(tau_meas)
    if kind == "cogging":
        j = int(rng.integers(0, 7))
        k = int(rng.integers(20, 61))
        out[:, j] = np.sin(k * m.q[:, j] + rng.uniform(0, 2 * math.pi))
        out[:, j] *= factor * noise[j] / _rms(out[:, j:j + 1])[0]
        return out, {"effect": "cogging", "joints": [j], "cycles_per_turn": k, "factor": factor}
    if kind == "cable":
        j = int(rng.choice([0, 5, 6]))
        q = m.q[:, j]
        x = q - (q.mean() + rng.uniform(-0.5, 0.5) * q.std())
        out[:, j] = -x
        out[:, j] *= factor * noise[j] / _rms(out[:, j:j + 1])[0]
        return out, {"effect": "cable_spring", "joints": [j], "stiffness_Nm_per_rad": float(out[0, j] / -x[0]),
                     "factor": factor}
    if kind == "crosstalk":
        j = int(rng.choice([4, 5, 6]))
        i = int(rng.choice([1, 3]))
        c = factor * noise[j] / _rms(tau_meas[:, i:i + 1])[0]
        out[:, j] = c * tau_meas[:, i]
        return out, {"effect": "crosstalk", "joints": [j], "from_joint": i, "coefficient": c, "factor": factor}
    if kind == "grasp":
        mass = float(rng.uniform(*PAYLOAD_KG))
        from franka_vs_gym.validation.effects import PlantChange, get_effect

        plant = PlantChange(base.copy())
        get_effect("payload").inject(plant, rng, 1.0)
        body = RigidBody(mass, np.asarray(plant.payload.com), np.asarray(plant.payload.inertia) * mass
                         / plant.payload.mass)
        tau = _torque(base.copy(payload=body), m) - _torque(base, m)
        T = float(m.time[-1])
        tg = float(rng.uniform(0.35, 0.65)) * T
        ramp = np.clip((m.time - tg) / 0.05, 0.0, 1.0)[:, None]
        return tau * ramp, {"effect": "grasp", "t_s": tg, "mass_kg": mass,
                            "com_flange_m": np.round(body.com, 4).tolist(),
                            "joints": [j for j in range(7) if _rms(tau)[j] >= noise[j]]}
    raise ValueError(f"unknown kind {kind!r}: choose from {', '.join(KINDS)}")


def _draw_setup(log: MeasurementLog, parts: list[str], seed: int, config: ModelConfig | None,
                noise: np.ndarray | None) -> tuple[np.random.Generator, ModelConfig, np.ndarray, Any, np.ndarray]:
    """What :func:`inject` and :func:`truth_effects` draw and size effects from: the seeded generator of ``parts``,
    the model the effects change (default: the FER without tool, the log's gravity), the noise floor (default: the
    cleaned log's estimate, at least 1e-3 Nm), the log's motion and the model's torque along it."""
    rng = np.random.default_rng([seed, sum(KINDS.index(p) + 1 for p in parts)])
    base = config if config is not None else ModelConfig(tool=Tool.none(), gravity=log.gravity)
    if noise is None:
        from franka_vs_gym.validation.signals import clean

        noise = clean(log).noise
    noise = np.maximum(np.asarray(noise, dtype=float), 1e-3)
    m = motion(log)
    return rng, base, noise, m, _torque(base, m)


def truth_effects(log: MeasurementLog, kind: str, seed: int, noise: np.ndarray | None = None,
                  config: ModelConfig | None = None) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Library effect(s) ``kind`` (one of :data:`LIBRARY_KINDS`, or "a+b") drawn and sized exactly as
    :func:`inject` sizes them on ``log``'s motion, written as the effect list of a ``franka-vs serve --truth`` file
    (the simulated plant then carries them while the robot's model does not, so a client's recording holds them
    with the simulator's own sampling, control loop and noise), and the truth (as :func:`inject` returns it)."""
    parts = kind.split("+")
    if not all(p in LIBRARY_KINDS for p in parts):
        raise ValueError(f"kind {kind!r}: a served truth takes library effects only ({', '.join(LIBRARY_KINDS)})")
    rng, base, noise, m, tau0 = _draw_setup(log, parts, seed, config, noise)
    effects, truth = [], []
    for part in parts:
        _, tr = _library(part, base, m, tau0, noise, rng)
        name = tr["effect"]
        if part == "payload":
            item = {"effect": name, "mass_kg": tr["mass_kg"], "com_flange_m": tr["com_flange_m"]}
        elif part == "tilt":
            item = {"effect": name, "gravity_m_per_s2": (np.asarray(base.gravity) + tr["delta_gravity_m_per_s2"])
                    .round(6).tolist()}
        elif part == "delay":
            item = {"effect": name, "delay_s": tr["delay_s"]}
        else:  # per-joint: the drawn value on its joint, nothing on the others
            key = next(k for k in tr if k not in ("effect", "joints", "factor"))
            v = np.zeros(7)
            v[tr["joints"][0]] = tr[key]
            item = {"effect": name, key: v.tolist()}
        effects.append(item)
        truth.append(tr)
    return effects, truth


def inject(log: MeasurementLog, kind: str, seed: int, config: ModelConfig | None = None,
           noise: np.ndarray | None = None) -> tuple[MeasurementLog, list[dict[str, Any]]]:
    """A copy of the real ``log`` with ``kind`` (one of :data:`KINDS`; "a+b" for two at once) added to its measured
    torque, and the truth (one dict per effect: name, joints touched, parameters). ``config`` is the model the
    effects change (default: the FER without tool, gravity of the log); ``noise`` (7,) Nm the noise floor that
    sizes them (default: the cleaned log's estimate)."""
    if kind not in KINDS and not all(p in KINDS for p in kind.split("+")):
        raise ValueError(f"unknown kind {kind!r}: choose from {', '.join(KINDS)}")
    rng, base, noise, m, tau0 = _draw_setup(log, kind.split("+"), seed, config, noise)
    tau = log.tau_J.copy()
    truth = []
    delay = 0.0
    for part in kind.split("+"):
        if part in LIBRARY_KINDS:
            add, tr = _library(part, base, m, tau0, noise, rng)
            if part == "delay":
                delay = tr["delay_s"]
        else:
            add, tr = _outside(part, base, m, tau, noise, rng)
        tau = tau + add
        truth.append(tr)
    if delay > 0:  # the measured torque (with its noise) lags the motion
        tau = np.column_stack([np.interp(m.time - delay, m.time, tau[:, j]) for j in range(7)])
    # rows the robot repeated (stale: q, dq and tau_J as in the row before) stay repeated, so cleaning drops them
    stale = np.nonzero((log.q[1:] == log.q[:-1]).all(axis=1) & (log.dq[1:] == log.dq[:-1]).all(axis=1)
                       & (log.tau_J[1:] == log.tau_J[:-1]).all(axis=1))[0] + 1
    for k in stale:
        tau[k] = tau[k - 1]
    new = MeasurementLog(log.time, log.q, log.dq, tau, tool=log.tool, gravity=log.gravity,
                         controller=log.controller, extra={**log.extra, "injected": truth}, source=log.source,
                         tool_declared=log.tool_declared)
    return new, truth


__all__ = ["COMPOUND_KINDS", "KINDS", "LIBRARY_KINDS", "OUTSIDE_KINDS", "distinct_rows", "every_kth", "inject",
           "motion", "truth_effects"]
