"""An independent generator of FER measurement logs with hidden effects, for judging the workbench on data it was
not developed on. It shares nothing with ``franka_vs_gym.validation.hidden``: no simulation and no controller (the
torque is the inverse dynamics of an analytic trajectory, as a perfectly tracking robot would measure it), its own
trajectory family (three incommensurate sinusoids per joint around a random pose), its own noise model, and its own
effect laws, written here from their physics rather than through the library's effect classes:

library-type effects (each a different law or implementation than the library's):
    ``viscous``  b dq;  ``coulomb``  F (2/pi) arctan(dq / 0.02);  ``stribeck``  (F_c + (F_s - F_c) exp(-(dq/v_s)^2))
    (2/pi) arctan(dq / 0.01);  ``armature``  I_r ddq;  ``offset``  constant;  ``payload``  Newton-Euler wrench of a
    rigid body at the flange mapped by the flange Jacobian;  ``tilt``  -(M J_com)^T dg;  ``delay``  the torque
    sensor lags by d.
effects outside the library:
    ``cogging``  A sin(k q_j + phase) on 2-4 joints (position ripple of the drive);  ``backlash``  the logged joint
    position differs from the link's by +-b/2 depending on the direction of motion (a dead zone between motor and
    link encoders);  ``drift``  Coulomb friction that decays as the joints warm up, F (1 + a exp(-t / T));
    ``disturbance``  a periodic torque A sin(2 pi f t + phase) on 1-2 joints.

``make_log(effects, seed)`` returns the log and the truth; magnitudes are drawn from the seed.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.description import FER
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.validation.logs import MeasurementLog

LIBRARY_TYPE = ("viscous", "coulomb", "stribeck", "armature", "offset", "payload", "tilt", "delay")
OUTSIDE = ("cogging", "backlash", "drift", "disturbance")
#: names the workbench may legitimately give each generated effect (step-shaped friction laws are one family)
STEP = {"coulomb_friction", "sigmoid_friction", "asymmetric_friction"}
ACCEPT = {"viscous": {"viscous_friction"}, "coulomb": STEP, "stribeck": STEP | {"stribeck_friction"},
          "armature": {"armature"}, "offset": {"torque_offset"}, "payload": {"payload"}, "tilt": {"gravity_tilt"},
          "delay": {"delay"}}
SCALE = np.array([1.0, 1.0, 0.8, 0.8, 0.3, 0.3, 0.15])


def _trajectory(rng: np.random.Generator, t: np.ndarray):
    lim = FER.limit_arrays()
    lo, hi = lim["q_min"] + 0.25, lim["q_max"] - 0.25
    q0 = np.clip(FER.neutral() + rng.uniform(-0.4, 0.4, 7), lo + 0.5, hi - 0.5)
    f = rng.uniform(0.04, 0.35, (7, 3))  # Hz
    a = rng.uniform(0.3, 1.0, (7, 3))
    ph = rng.uniform(0, 2 * np.pi, (7, 3))
    w = 2 * np.pi * f
    vmax = rng.uniform(0.5, 1.1)  # rad/s, bound of the summed peak speeds
    s = np.minimum(vmax / (a * w).sum(axis=1), np.minimum(q0 - lo, hi - q0) / a.sum(axis=1))
    a = a * s[:, None]
    arg = w[None] * t[:, None, None] + ph[None]
    q = q0 + (a * np.sin(arg)).sum(axis=2)
    dq = (a * w * np.cos(arg)).sum(axis=2)
    ddq = -(a * w ** 2 * np.sin(arg)).sum(axis=2)
    return q, dq, ddq


def _payload_torque(fm: FrankaModel, q, dq, ddq, mass, com, inertia) -> np.ndarray:
    model, data = fm.model, fm.data
    fid = model.getFrameId("flange")
    body = pin.Inertia(mass, np.asarray(com), np.asarray(inertia))
    out = np.empty_like(q)
    g = model.gravity.linear.copy()
    for k in range(len(q)):
        pin.forwardKinematics(model, data, q[k], dq[k], ddq[k])
        pin.computeJointJacobians(model, data, q[k])
        pin.updateFramePlacements(model, data)
        R = data.oMf[fid].rotation
        v = pin.getFrameVelocity(model, data, fid, pin.LOCAL)
        a = pin.getFrameAcceleration(model, data, fid, pin.LOCAL)
        a_eff = pin.Motion(a.linear - R.T @ g, a.angular)  # gravity as an upward acceleration of the frame
        f = body * a_eff + v.cross(body * v)
        J = pin.getFrameJacobian(model, data, fid, pin.LOCAL)
        out[k] = J.T @ f.vector
    return out


def _tilt_torque(fm: FrankaModel, q, dg) -> np.ndarray:
    model, data = fm.model, fm.data
    out = np.empty_like(q)
    for k in range(len(q)):
        Jc = pin.jacobianCenterOfMass(model, data, q[k])
        out[k] = -data.mass[0] * (Jc.T @ dg)
    return out


def make_log(effects: tuple[str, ...] | list[str], seed: int, duration: float = 10.0, rate: float = 1000.0
             ) -> tuple[MeasurementLog, dict]:
    """A log of ``duration`` s at ``rate`` Hz with the given hidden effects (names of LIBRARY_TYPE and OUTSIDE)."""
    rng = np.random.default_rng(10_000 + seed)
    fm = FrankaModel(ModelConfig())  # what the experimenter believes (and the plant's rigid body)
    n = int(duration * 1000)
    t = np.arange(n) / 1000.0
    q, dq, ddq = _trajectory(rng, t)
    tau = np.array([fm.inverse_dynamics(q[k], dq[k], ddq[k]) for k in range(n)])
    q_logged = q.copy()
    truth: dict = {}
    delay = 0.0
    for e in effects:
        m = rng.uniform(0.5, 1.0)
        if e == "viscous":
            b = 0.6 * m * SCALE
            tau += b * dq
            truth[e] = {"b": b.tolist()}
        elif e == "coulomb":
            F = 0.9 * m * SCALE
            tau += F * (2 / np.pi) * np.arctan(dq / 0.02)
            truth[e] = {"F": F.tolist()}
        elif e == "stribeck":
            Fc = 0.7 * m * SCALE
            Fs = Fc * rng.uniform(1.5, 2.5)
            vs = rng.uniform(0.05, 0.15)
            tau += (Fc + (Fs - Fc) * np.exp(-(dq / vs) ** 2)) * (2 / np.pi) * np.arctan(dq / 0.01)
            truth[e] = {"Fc": Fc.tolist(), "vs": vs}
        elif e == "armature":
            Ir = 0.3 * m * SCALE
            tau += Ir * ddq
            truth[e] = {"Ir": Ir.tolist()}
        elif e == "offset":
            o = 0.8 * m * SCALE * rng.choice([-1.0, 1.0], 7)
            tau += o
            truth[e] = {"offset": o.tolist()}
        elif e == "payload":
            mass = 1.5 * m
            com = np.array([rng.uniform(-0.03, 0.03), rng.uniform(-0.03, 0.03), rng.uniform(0.02, 0.12)])
            inertia = np.diag(rng.uniform(0.5, 1.5, 3)) * mass * 0.003
            tau += _payload_torque(fm, q, dq, ddq, mass, com, inertia)
            truth[e] = {"mass": mass, "com": com.tolist()}
        elif e == "tilt":
            ang = math.radians(5.0 * m)
            az = rng.uniform(0, 2 * np.pi)
            g0 = np.array([0.0, 0.0, -9.81])
            g = 9.81 * np.array([math.sin(ang) * math.cos(az), math.sin(ang) * math.sin(az), -math.cos(ang)])
            tau += _tilt_torque(fm, q, g - g0)
            truth[e] = {"tilt_deg": math.degrees(ang)}
        elif e == "delay":
            delay = 0.02 * m
            truth[e] = {"delay_s": delay}
        elif e == "cogging":
            js = rng.choice(7, size=rng.integers(2, 5), replace=False)
            k = rng.uniform(4.0, 16.0, 7)
            ph = rng.uniform(0, 2 * np.pi, 7)
            A = np.zeros(7)
            A[js] = 1.0 * m * SCALE[js]
            tau += A * np.sin(k * q + ph)
            truth[e] = {"joints": sorted(js.tolist()), "A": A.tolist(), "k": k.tolist()}
        elif e == "backlash":
            b = rng.uniform(0.01, 0.025) * m / 0.75
            q_logged = q + 0.5 * b * np.tanh(dq / 0.01)  # the measured position leads/lags with the direction
            truth[e] = {"b_rad": b}
        elif e == "drift":
            F = 0.9 * m * SCALE
            a = rng.uniform(1.0, 2.0)
            T = rng.uniform(2.0, 5.0)
            tau += F * (1 + a * np.exp(-t / T))[:, None] * (2 / np.pi) * np.arctan(dq / 0.02)
            truth[e] = {"F": F.tolist(), "a": a, "T_s": T}
        elif e == "disturbance":
            js = rng.choice(7, size=rng.integers(1, 3), replace=False)
            f = rng.uniform(0.5, 4.0)
            A = np.zeros(7)
            A[js] = 1.0 * m * SCALE[js]
            tau += A * np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi))[:, None]
            truth[e] = {"joints": sorted(js.tolist()), "A": A.tolist(), "f_hz": f}
        else:
            raise ValueError(f"unknown generated effect {e!r}")
    if delay > 0:
        tau = np.column_stack([np.interp(t - delay, t, tau[:, j]) for j in range(7)])
    sig = rng.uniform(0.5, 1.5) * np.array([0.3, 0.3, 0.25, 0.25, 0.1, 0.1, 0.06]) * rng.uniform(0.7, 1.3, 7)
    tau_meas = tau + rng.normal(size=tau.shape) * sig
    q_meas = q_logged + rng.normal(0, 2e-5, q.shape)
    dq_meas = dq + rng.normal(0, 1.5e-3, dq.shape)
    step = int(round(1000 / rate))
    sl = slice(0, n, step)
    log = MeasurementLog(t[sl], q_meas[sl], dq_meas[sl], tau_meas[sl], tool="franka_hand",
                         extra={"generator": "tests/independent_logs.py"})
    return log, {"effects": list(effects), "params": truth, "noise": sig.tolist()}


def score(effects: list[str], diagnosis) -> dict:
    """Right or wrong, for one log: ``none`` logs must give verdict none and explained; library-type effects must be
    named exactly (each by an accepted name, nothing else selected); outside effects must give explained false."""
    sel = [s.effect for s in diagnosis.selection]
    lib = [e for e in effects if e in ACCEPT]
    out = [e for e in effects if e in OUTSIDE]
    if not effects:
        ok = diagnosis.verdict == "none" and diagnosis.explained
        return {"category": "none", "ok": ok, "selected": sel}
    if out:
        # the worst answer is a confident wrong name: outside effects must be flagged as unexplained
        ok = not diagnosis.explained
        named_ok = all(any(s in ACCEPT[e] for s in sel) for e in lib)
        return {"category": "outside" if not lib else "mixed", "ok": ok and named_ok, "selected": sel,
                "explained": diagnosis.explained}
    hit = all(any(s in ACCEPT[e] for s in sel) for e in lib)
    extra = [s for s in sel if not any(s in ACCEPT[e] for e in lib)]
    floor = bool(np.all(diagnosis.rmse_tau_selected <= 1.1 * diagnosis.noise_floor))
    cat = "single" if len(lib) == 1 else f"compound{len(lib)}"
    return {"category": cat, "ok": hit and not extra, "subset_ok": hit, "selected": sel, "at_floor": floor,
            "explained": diagnosis.explained}
