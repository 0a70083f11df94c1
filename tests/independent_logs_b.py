"""A second independent generator of FER measurement logs (generator B), written from the log format and the
public effect names only, to judge the workbench on data that differs from both the development generator
(``franka_vs_gym.validation.hidden``) and generator A (``tests/independent_logs.py``) the way real recordings do.

Plant: the link follows an analytic trajectory exactly (a perfectly tracking robot), the link-side torque is the
inverse dynamics of the model the experimenter believes (``ModelConfig()``: the FER with the Franka Hand and the
Gaz et al. 2019 sigmoid friction) plus the hidden effects, evaluated at the **true** link state; what is logged goes
through a sensor chain:

- trajectories of four styles (``STYLES[seed % 4]``, or forced; ``lugre`` always ``p2p``, its memory shows in
  rests): ``p2p`` point-to-point minimum-jerk moves with rests
  (velocity reversals and zero-velocity holds), ``slow`` multi-sines in 0.03-0.25 Hz, ``fast`` small multi-sines in
  0.4-1.6 Hz, ``mixed`` a 0.08-0.6 Hz multi-sine whose envelope drops to near-static segments;
- torque: white noise plus AR(1)-coloured noise plus a little 1/f noise, a slowly wandering offset (up to 6 % of the
  noise, zero on average over the log), quantised to 0.002-0.01 Nm;
- position: link encoder quantised to 2 pi / 2^19..2^21 rad; velocity: libfranka-like, the backward difference of
  the quantised position through a causal first-order low-pass at 250-500 Hz (so dq lags by about a millisecond);
- timing: 1 kHz logs carry robot time in whole milliseconds with 0.5-2 % of rows dropped (and a few bursts of
  3-15 ms) and 0.2 % stale repeats; 100 Hz and 30 Hz logs are what a ROS publisher writes from the same 1 kHz
  stream: the newest sample at each jittered publish instant (no anti-alias filter), stamped with the publish time,
  1 % of messages lost.

Library-type effects (own laws; magnitudes from published FER ranges, Gaz et al. 2019 for friction):
    ``viscous``   b dq, b 0.1-0.4 Nm s/rad (scaled down on the wrist);
    ``coulomb``   a change of the friction level, dF (1 - exp(-abs(dq)/v0)) sign(dq), dF +-25-60 % of Gaz phi1 on
                  3-7 joints, v0 5-30 mrad/s;
    ``asym``      direction-dependent friction change: F+ on positive, -F- on negative velocities, smoothed by erf;
    ``loadfric``  harmonic-drive efficiency: mu abs(rigid-body load torque) tanh(dq / 0.02), mu 0.04-0.12;
    ``armature``  rotor inertia reflected through the gear, I ddq, I 0.05-0.3 kg m^2 (less on the wrist);
    ``offset``    constant sensor bias on 2-7 joints, 0.1-0.6 Nm;
    ``payload``   0.2-3 kg body at the flange (CoM within 5 cm laterally, 0-15 cm out, box inertia), added to the
                  last link of a copy of the pinocchio model;
    ``tilt``      base mounted 0.5-3 degrees off level (gravity rotated);
    ``delay``     the torque reading lags by 2-5 ms.
Effects outside the library (a real FER can show each):
    ``elastic``   joint compliance: the logged position is the motor side, q_link + d with d from a lightly damped
                  torsional spring (8-20 Hz) driven by the link torque (quasi-static deflection plus ringing);
    ``lugre``     presliding friction with memory (LuGre-type bristle state) replacing a sharp Coulomb step on 2-4
                  joints: the friction force persists through rests and builds over a few mrad after reversals;
    ``posfric``   friction whose level varies with the joint position (half to two periods over the visited range);
    ``cable``     a cable/hose spring on joints 1-4: k1 (q - q0) + k3 (q - q0)^3;
    ``ripple``    harmonic-drive torque ripple, A sin(m q + phase) with m = 80-240 cycles per link turn;
    ``tempvisc``  viscous friction (cold: 0.6-1.2 Nm s/rad) that falls to 30-40 % as the joint warms with the
                  energy it dissipates;
    ``contact``   one or two 0.15-0.6 s contacts: a 5-20 N force on the end effector, J^T F.

``make_logs(effects, seed, rates=(1000, 100, 30))`` returns ``({rate: log}, truth)``; ``score(...)`` judges a
diagnosis; the truth includes each effect's signal energy at each rate (sum over samples and joints of
(effect torque / white noise sigma)^2), below which an effect cannot be required to be found.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from scipy.linalg import expm
from scipy.special import erf

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.description import FER
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.validation.logs import MeasurementLog

LIBRARY_TYPE = ("viscous", "coulomb", "asym", "loadfric", "armature", "offset", "payload", "tilt", "delay")
OUTSIDE = ("elastic", "lugre", "posfric", "cable", "ripple", "tempvisc", "contact")
STYLES = ("p2p", "slow", "fast", "mixed")
#: the step-friction laws count as one family (as for generator A)
STEP = {"coulomb_friction", "sigmoid_friction", "asymmetric_friction"}
ACCEPT = {"viscous": {"viscous_friction"}, "coulomb": STEP, "asym": STEP,
          "loadfric": {"load_dependent_friction"}, "armature": {"armature"}, "offset": {"torque_offset"},
          "payload": {"payload"}, "tilt": {"gravity_tilt"}, "delay": {"delay"}}
#: a library effect whose signal energy is below this cannot be required (sum of squared SNR over the log)
REQUIRED_ENERGY = 300.0
W = np.array([1.0, 1.0, 0.8, 0.8, 0.4, 0.4, 0.25])  # rough wrist scaling of magnitudes
DT = 1e-3


# ---------------------------------------------------------------- trajectories (true link motion at 1 kHz)
def _limits():
    lim = FER.limit_arrays()
    return lim["q_min"] + 0.3, lim["q_max"] - 0.3


def _fit_to_limits(q: np.ndarray) -> np.ndarray:
    lo, hi = _limits()
    c = 0.5 * (q.max(axis=0) + q.min(axis=0))
    half = 0.5 * (q.max(axis=0) - q.min(axis=0)) + 1e-12
    room = 0.5 * (hi - lo)
    s = np.minimum(1.0, room / half)
    q = c + (q - c) * s
    shift = np.clip(q.min(axis=0), lo, None) - q.min(axis=0) + np.clip(q.max(axis=0), None, hi) - q.max(axis=0)
    return q + shift


def _p2p(rng, n, fine):
    """Joint-space point-to-point moves (minimum jerk, synchronised) with rests between them."""
    lo, hi = _limits()
    centre = np.clip(FER.neutral() + rng.uniform(-0.3, 0.3, 7), lo + 0.6, hi - 0.6)
    vmax = rng.uniform(0.4, 1.2)
    out = np.empty((n * fine, 7))
    k, cur = 0, centre.copy()
    while k < len(out):
        rest = int(rng.uniform(0.15, 1.2) / (DT / fine))
        out[k:k + rest] = cur
        k += rest
        span = rng.uniform(0.2, 0.9) * np.minimum(cur - lo, hi - cur).clip(0.1)
        target = np.clip(centre + rng.uniform(-1, 1, 7) * span * 1.5, lo, hi)
        if rng.random() < 0.25:  # a small fine-positioning move
            target = cur + 0.1 * (target - cur)
        T = max(0.4, 1.875 * np.abs(target - cur).max() / vmax)
        m = int(T / (DT / fine))
        s = np.linspace(0, 1, m, endpoint=False)
        prof = 10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5
        out[k:k + m] = (cur + prof[:, None] * (target - cur))[:max(0, min(m, len(out) - k))]
        k += m
        cur = target
    return out


def _multisine(rng, n, fine, band, n_sines, amp_scale, envelope=False):
    lo, hi = _limits()
    t = np.arange(n * fine) * DT / fine
    centre = np.clip(FER.neutral() + rng.uniform(-0.35, 0.35, 7), lo + 0.5, hi - 0.5)
    f = rng.uniform(band[0], band[1], (7, n_sines))
    w = 2 * np.pi * f
    a = rng.uniform(0.2, 1.0, (7, n_sines)) / w  # roughly equal velocity per sine
    ph = rng.uniform(0, 2 * np.pi, (7, n_sines))
    q = (a[None] * np.sin(w[None] * t[:, None, None] + ph[None])).sum(axis=2)
    vpk = np.abs(np.gradient(q, t, axis=0)).max(axis=0)
    q = q * (amp_scale * rng.uniform(0.6, 1.0, 7) / vpk)
    if envelope:
        # near-static segments: the motion fades to 3 % for 1-2.5 s, twice or three times per log
        e = np.ones_like(t)
        for _ in range(rng.integers(2, 4)):
            t0, L, r = rng.uniform(0, t[-1]), rng.uniform(1.5, 3.0), 0.6
            x = np.clip(np.minimum((t - t0) / r, (t0 + L - t) / r), 0, 1)
            e = e * (1 - 0.97 * (10 * x ** 3 - 15 * x ** 4 + 6 * x ** 5))  # C2 fades
        q = q * e[:, None]
    return _fit_to_limits(centre + q)


def trajectory(rng: np.random.Generator, n: int, style: str):
    """(q, dq, ddq), each (n, 7), at 1 kHz: the true link motion of the given style."""
    fine, n_all = 4, n + 2000  # one more second at each end, cut (no edge effects)
    n, n_out = n_all, n
    if style == "p2p":
        qf = _p2p(rng, n, fine)
        # minimum-jerk profiles are C2; smooth the corners of the rests (no infinite jerk) with a 20 ms window
        k = np.hanning(81)
        k /= k.sum()
        pad = np.pad(qf, ((40, 40), (0, 0)), mode="edge")
        qf = np.stack([np.convolve(pad[:, j], k, mode="valid") for j in range(7)], axis=1)
    elif style == "slow":
        qf = _multisine(rng, n, fine, (0.03, 0.25), int(rng.integers(4, 7)), rng.uniform(0.4, 1.0))
    elif style == "fast":
        qf = _multisine(rng, n, fine, (0.4, 1.6), int(rng.integers(4, 8)), rng.uniform(0.3, 0.8))
    elif style == "mixed":
        qf = _multisine(rng, n, fine, (0.08, 0.6), int(rng.integers(5, 9)), rng.uniform(0.5, 1.2), envelope=True)
    else:
        raise ValueError(f"unknown trajectory style {style!r}")
    h = DT / fine
    dqf = np.gradient(qf, h, axis=0)
    ddqf = np.gradient(dqf, h, axis=0)
    sl = slice(1000 * fine, (1000 + n_out) * fine, fine)
    return qf[sl], dqf[sl], ddqf[sl]


# ---------------------------------------------------------------- dynamics helpers (pinocchio directly)
def _rnea(model, q, dq, ddq):
    data = model.createData()
    return np.array([pin.rnea(model, data, q[k], dq[k], ddq[k]) for k in range(len(q))])


def _gaz_phi1():
    return np.asarray(FER.friction.phi1, dtype=float)


def _smooth_noise(rng, n, alpha):
    """Noise with power spectrum ~ 1/f^alpha, unit RMS, shape (n,)."""
    spec = np.fft.rfft(rng.normal(size=n))
    f = np.fft.rfftfreq(n)
    f[0] = f[1]
    x = np.fft.irfft(spec / f ** (alpha / 2), n)
    return (x - x.mean()) / x.std()


# ---------------------------------------------------------------- the generator
def make_logs(effects, seed: int, duration: float = 10.0, rates=(1000.0, 100.0, 30.0), style: str | None = None,
              noise_seed: int | None = None) -> tuple[dict[float, MeasurementLog], dict]:
    """Logs of ``duration`` s at each rate (Hz) with the given hidden effects, and the truth. ``noise_seed``: draw
    the sensor chain (noise, quantisation, velocity filter) from its own seed, the motion and effects staying those
    of ``seed`` (None: everything from ``seed``, as always)."""
    effects = list(effects)
    rng = np.random.default_rng(77_000 + seed)
    if style is None:
        style = "p2p" if "lugre" in effects else STYLES[seed % len(STYLES)]
    n = int(round(duration / DT))
    t = np.arange(n) * DT
    q, dq, ddq = trajectory(rng, n, style)
    fm = FrankaModel(ModelConfig())
    model = fm.model
    q_pos = q.copy()  # the position the encoders report (motor side under "elastic")
    parts: dict[str, np.ndarray] = {}
    truth: dict = {"style": style, "params": {}}
    delay = 0.0
    rigid = _rnea(model, q, dq, ddq)
    base = rigid + fm.friction(dq)
    phi1 = _gaz_phi1()
    for e in effects:
        u = rng.uniform(0.0, 1.0)
        P = truth["params"]
        if e == "viscous":
            b = (0.1 + 0.3 * u) * W * rng.uniform(0.7, 1.0, 7)
            parts[e] = b * dq
            P[e] = {"b": b.round(4).tolist()}
        elif e == "coulomb":
            js = rng.choice(7, int(rng.integers(3, 8)), replace=False)
            dF = np.zeros(7)
            dF[js] = (0.25 + 0.35 * rng.uniform(size=len(js))) * phi1[js] * rng.choice([-1.0, 1.0], len(js))
            v0 = rng.uniform(0.005, 0.03)
            parts[e] = dF * (1 - np.exp(-np.abs(dq) / v0)) * np.sign(dq)
            P[e] = {"dF": dF.round(4).tolist(), "v0": v0}
        elif e == "asym":
            Fp = (0.2 + 0.4 * rng.uniform(size=7)) * phi1
            Fm = rng.uniform(-0.3, 0.05, 7) * phi1
            v0 = rng.uniform(0.01, 0.03)
            parts[e] = np.where(dq > 0, Fp, Fm) * erf(dq / v0)
            P[e] = {"F_plus": Fp.round(4).tolist(), "F_minus": Fm.round(4).tolist()}
        elif e == "loadfric":
            mu = rng.uniform(0.04, 0.12, 7)
            parts[e] = mu * np.abs(rigid) * np.tanh(dq / 0.02)
            P[e] = {"mu": mu.round(4).tolist()}
        elif e == "armature":
            Ia = (0.05 + 0.25 * u) * W ** 2 * rng.uniform(0.6, 1.0, 7)
            parts[e] = Ia * ddq
            P[e] = {"I": Ia.round(4).tolist()}
        elif e == "offset":
            js = rng.choice(7, int(rng.integers(2, 8)), replace=False)
            o = np.zeros(7)
            o[js] = rng.uniform(0.1, 0.6, len(js)) * W[js] * rng.choice([-1.0, 1.0], len(js))
            parts[e] = np.broadcast_to(o, q.shape).copy()
            P[e] = {"offset": o.round(4).tolist()}
        elif e == "payload":
            mass = rng.uniform(0.2, 3.0)
            com = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(0.0, 0.15)])
            dims = rng.uniform(0.05, 0.2, 3)
            inertia = np.diag(mass / 12 * (dims[[1, 0, 0]] ** 2 + dims[[2, 2, 1]] ** 2))
            m2 = model.copy()
            fl = m2.frames[m2.getFrameId("flange")].placement
            m2.inertias[7] = m2.inertias[7] + fl.act(pin.Inertia(mass, com, inertia))
            parts[e] = _rnea(m2, q, dq, ddq) - rigid
            P[e] = {"mass": mass, "com": com.round(4).tolist()}
        elif e == "tilt":
            ang, az = math.radians(rng.uniform(0.5, 3.0)), rng.uniform(0, 2 * np.pi)
            g = 9.81 * np.array([math.sin(ang) * math.cos(az), math.sin(ang) * math.sin(az), -math.cos(ang)])
            m2 = model.copy()
            m2.gravity.linear = g
            parts[e] = _rnea(m2, q, dq, ddq) - rigid
            P[e] = {"tilt_deg": math.degrees(ang)}
        elif e == "delay":
            delay = rng.uniform(0.002, 0.005)
            P[e] = {"delay_s": delay}
        elif e == "elastic":
            K = np.where(np.arange(7) < 4, rng.uniform(0.6e4, 1.6e4, 7), rng.uniform(0.15e4, 0.5e4, 7))
            Mdiag = np.array([fm.mass_matrix(q[k]).diagonal() for k in range(0, n, 50)]).mean(axis=0)
            w = np.sqrt(K / Mdiag).clip(2 * np.pi * 8, 2 * np.pi * 20)
            zeta = rng.uniform(0.03, 0.1, 7)
            # motor-side minus link position: d'' + 2 zeta w d' + w^2 d = w^2 tau / K (exact ZOH steps)
            tau_drive = base
            d = np.zeros((n, 7))
            x = np.stack([tau_drive[0] / K, np.zeros(7)], axis=1)  # (7, 2): d, d'
            for j in range(7):
                A = np.array([[0.0, 1.0], [-w[j] ** 2, -2 * zeta[j] * w[j]]])
                Ad = expm(A * DT)
                Bd = np.linalg.solve(A, (Ad - np.eye(2)) @ np.array([0.0, w[j] ** 2 / K[j]]))
                xj = x[j].copy()
                for k in range(n):
                    d[k, j] = xj[0]
                    xj = Ad @ xj + Bd * tau_drive[k, j]
            q_pos = q + d
            P[e] = {"K": K.round(0).tolist(), "f_hz": (w / 2 / np.pi).round(2).tolist(),
                    "max_deflection_rad": float(np.abs(d).max())}
        elif e == "lugre":
            js = rng.choice(7, int(rng.integers(2, 5)), replace=False)
            Fc = np.zeros(7)
            Fc[js] = rng.uniform(0.4, 0.9, len(js)) * phi1[js]
            xp = rng.uniform(0.5e-3, 3e-3, 7)  # presliding displacement, rad
            z = np.zeros(7)  # bristle force, Nm
            f = np.zeros((n, 7))
            dx = dq * DT
            for k in range(n):
                zinf = np.sign(dx[k]) * Fc
                z = zinf + (z - zinf) * np.exp(-np.abs(dx[k]) / xp)
                f[k] = z
            parts[e] = f - Fc * np.sign(dq) * (np.abs(dq) > 1e-9)
            P[e] = {"joints": sorted(js.tolist()), "Fc": Fc.round(4).tolist(), "x_presliding": xp.round(5).tolist()}
        elif e == "posfric":
            js = rng.choice(7, int(rng.integers(2, 4)), replace=False)
            A = np.zeros(7)
            A[js] = rng.uniform(0.5, 1.0, len(js)) * phi1[js]
            span = q.max(axis=0) - q.min(axis=0) + 1e-3
            k = np.pi * rng.uniform(1.0, 3.0, 7) / span
            ph = rng.uniform(0, 2 * np.pi, 7)
            parts[e] = A * np.cos(k * (q - q.min(axis=0)) + ph) * np.tanh(dq / 0.01)
            P[e] = {"joints": sorted(js.tolist()), "A": A.round(4).tolist()}
        elif e == "cable":
            js = rng.choice(4, int(rng.integers(1, 3)), replace=False)
            k1, k3 = np.zeros(7), np.zeros(7)
            k1[js] = rng.uniform(1.0, 3.0, len(js))
            k3[js] = rng.uniform(1.0, 4.0, len(js))
            q0 = q.mean(axis=0) + rng.uniform(-0.3, 0.3, 7)
            parts[e] = k1 * (q - q0) + k3 * (q - q0) ** 3
            P[e] = {"joints": sorted(js.tolist()), "k1": k1.round(3).tolist(), "k3": k3.round(3).tolist()}
        elif e == "ripple":
            js = rng.choice(7, int(rng.integers(1, 4)), replace=False)
            A = np.zeros(7)
            A[js] = rng.uniform(0.25, 0.6, len(js)) * W[js]
            m = rng.integers(80, 121, 7) * rng.choice([1, 2], 7)
            parts[e] = A * np.sin(m * q + rng.uniform(0, 2 * np.pi, 7))
            P[e] = {"joints": sorted(js.tolist()), "A": A.round(4).tolist(), "cycles_per_turn": m.tolist()}
        elif e == "tempvisc":
            b0 = (0.6 + 0.6 * u) * W  # cold grease: up to about twice the warm viscosity
            E = np.cumsum(b0 * dq ** 2, axis=0) * DT  # dissipated energy, J (at the cold coefficient)
            E0 = 0.3 * E[-1] + 1e-9
            b = b0 * (0.3 + 0.7 * np.exp(-E / E0))
            parts[e] = b * dq
            P[e] = {"b_cold": b0.round(4).tolist(), "b_end_ratio": (b[-1] / b0).round(3).tolist()}
        elif e == "contact":
            data = model.createData()
            fid = model.getFrameId("ee")
            env = np.zeros(n)
            F = np.zeros((n, 3))
            for _ in range(int(rng.integers(1, 3))):
                t0, L = rng.uniform(1.0, duration - 1.0), rng.uniform(0.15, 0.6)
                x = np.clip((t - t0) / L, 0, 1)
                bump = np.sin(np.pi * x) ** 2
                d = rng.normal(size=3)
                F += bump[:, None] * rng.uniform(5, 20) * d / np.linalg.norm(d)
                env = np.maximum(env, bump)
            tau_c = np.zeros((n, 7))
            for k in np.nonzero(env > 1e-6)[0]:
                J = pin.computeFrameJacobian(model, data, q[k], fid, pin.LOCAL_WORLD_ALIGNED)
                tau_c[k] = -J[:3].T @ F[k]
            parts[e] = tau_c
            P[e] = {"force_n": float(np.linalg.norm(F, axis=1).max())}
        else:
            raise ValueError(f"unknown generated effect {e!r}")
    tau = base + sum(parts.values()) if parts else base.copy()
    if delay > 0:
        tau_d = np.column_stack([np.interp(t - delay, t, tau[:, j]) for j in range(7)])
        parts["delay"] = tau_d - tau
        tau = tau_d
    # -------------------------------------------------------- sensor chain at 1 kHz
    if noise_seed is not None:
        rng = np.random.default_rng((88_000, seed, noise_seed))
    sig = rng.uniform(0.6, 1.4) * np.array([0.25, 0.3, 0.2, 0.25, 0.1, 0.1, 0.05]) * rng.uniform(0.8, 1.25, 7)
    phi = rng.uniform(0.2, 0.6)
    white = rng.normal(size=(n, 7))
    ar = np.empty_like(white)
    ar[0] = white[0]
    e2 = rng.normal(size=(n, 7))
    for k in range(1, n):
        ar[k] = phi * ar[k - 1] + math.sqrt(1 - phi ** 2) * e2[k]
    pink = np.stack([_smooth_noise(rng, n, 1.0) for _ in range(7)], axis=1)
    # a slowly wandering offset, zero on average over the log (a constant bias would be a real torque_offset), of
    # at most 6 % of the joint's noise (a larger drift is structure a diagnosis should report)
    drift = np.outer(np.sin(2 * np.pi * t / duration * rng.uniform(0.5, 1.0) + rng.uniform(0, 6.3)),
                     rng.uniform(-0.06, 0.06, 7) * sig)
    drift -= drift.mean(axis=0)
    noise = sig * (0.85 * white + 0.45 * ar + 0.06 * pink) + drift
    lsb_tau = rng.choice([0.002, 0.005, 0.01])
    tau_meas = np.round((tau + noise) / lsb_tau) * lsb_tau
    lsb_q = 2 * np.pi / 2 ** int(rng.integers(19, 22))
    q_meas = np.round(q_pos / lsb_q) * lsb_q
    dq_raw = np.vstack([dq[:1], np.diff(q_meas, axis=0) / DT])
    fc = rng.uniform(250, 500)
    a = math.exp(-2 * np.pi * fc * DT)
    dq_meas = np.empty_like(dq_raw)
    dq_meas[0] = dq[0]
    for k in range(1, n):
        dq_meas[k] = a * dq_meas[k - 1] + (1 - a) * dq_raw[k]
    truth.update({"effects": effects, "noise_sigma": (sig * math.sqrt(0.85 ** 2 + 0.45 ** 2 + 0.06 ** 2)).tolist(),
                  "tau_lsb": lsb_tau, "q_lsb": lsb_q, "dq_filter_hz": fc, "energy": {}})
    logs: dict[float, MeasurementLog] = {}
    for rate in rates:
        idx, stamps = _sampling(np.random.default_rng((77_000 + seed, int(rate))), t, rate)
        energy = {e: float(((p[idx] / sig) ** 2).sum()) for e, p in parts.items()}
        truth["energy"][rate] = energy
        logs[rate] = MeasurementLog(stamps, q_meas[idx], dq_meas[idx], tau_meas[idx], tool="franka_hand",
                                    extra={"generator": "tests/independent_logs_b.py"})
    return logs, truth


def _sampling(rng, t, rate):
    """Indices of the 1 kHz samples a logger at ``rate`` keeps, and the time stamps it writes."""
    n = len(t)
    if rate >= 999.0:
        keep = rng.random(n) > rng.uniform(0.005, 0.02)
        for _ in range(int(rng.integers(0, 4))):
            k0 = int(rng.integers(100, n - 100))
            keep[k0:k0 + int(rng.integers(3, 16))] = False
        keep[0] = keep[-1] = True
        idx = np.nonzero(keep)[0]
        stale = rng.random(len(idx)) < 0.002
        stale[0] = False
        idx_vals = idx.copy()
        idx_vals[stale] = idx_vals[np.nonzero(stale)[0] - 1]  # the robot re-sent the previous state
        return idx_vals, np.round(t[idx] * 1000) / 1000  # robot time in whole ms
    period = 1.0 / rate
    pub = np.arange(0.0, t[-1], period)
    pub = pub + rng.normal(0, 0.08 * period, len(pub)).clip(-0.3 * period, 0.3 * period)
    pub = np.sort(pub.clip(0, t[-1]))
    keep = rng.random(len(pub)) > 0.01
    pub = pub[keep]
    idx = np.floor(pub / DT + 1e-9).astype(int).clip(0, len(t) - 1)  # the newest 1 kHz sample
    stamps = pub + rng.normal(0, 2e-4, len(pub))
    stamps = np.maximum.accumulate(stamps)
    return idx, stamps


def make_log(effects, seed: int, duration: float = 10.0, rate: float = 1000.0, style: str | None = None,
             noise_seed: int | None = None):
    """One log at one rate: ``(log, truth)``."""
    logs, truth = make_logs(effects, seed, duration, (rate,), style, noise_seed)
    return logs[rate], truth


def score(effects, diagnosis, truth: dict, rate: float) -> dict:
    """Right or wrong for one log. Clean: verdict none and explained. Library-type effects only: every effect
    whose signal energy reaches REQUIRED_ENERGY named by an accepted name, nothing outside the accepted names
    selected, and ``explained``... not required (a log can keep unexplained structure of the sensor) but
    recorded. Any effect outside the library: ``explained: false``; library effects present must be named."""
    effects = list(effects)
    sel = [s.effect for s in diagnosis.selection]
    energy = truth["energy"][rate]
    lib = [e for e in effects if e in ACCEPT]
    required = [e for e in lib if energy.get(e, 0.0) >= REQUIRED_ENERGY]
    accepted = set().union(*(ACCEPT[e] for e in lib)) if lib else set()
    wrong = [s for s in sel if s not in accepted]
    hit = all(any(s in ACCEPT[e] for s in sel) for e in required)
    out = [e for e in effects if e not in ACCEPT]
    base = {"selected": sel, "explained": bool(diagnosis.explained), "wrong_names": wrong,
            "required": required}
    if not effects:
        return {**base, "category": "none", "ok": diagnosis.verdict == "none" and bool(diagnosis.explained)}
    if out:
        cat = "outside" if not lib else "outside+library"
        # a confident wrong name (explained true with a name that fits none of the hidden effects) is the worst
        return {**base, "category": cat, "ok": (not diagnosis.explained) and hit,
                "confident_wrong": bool(diagnosis.explained and wrong)}
    cat = "single" if len(lib) == 1 else f"compound{len(lib)}"
    return {**base, "category": cat, "ok": hit and not wrong, "confident_wrong": bool(diagnosis.explained and wrong)}
