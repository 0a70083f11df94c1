"""What remains after the selected effects: is it noise, or structure the library cannot name?

For every joint j the residual ``r_j`` of the selected model is regressed, with the same contiguous-block
cross-validation as the selection, on generic feature groups that make no assumption about the physical law:

================  ==========================================================================================
group             features
================  ==========================================================================================
``constant``      an intercept (an offset left over)
``position``      piecewise-constant in 16 quantile bins of q_j (any smooth or stepped function of the pose)
``periodic_q``    sin/cos(k q_j), the best k of 1..``K_MAX`` cycles per turn (cogging, encoder errors, and the
                  torque ripple of a strain-wave gear at twice the wave generator's turns: 2 x the gear ratio,
                  up to about 320 per link turn for ratios up to 160)
``velocity``      16 quantile bins of dq_j (friction-like laws of any shape: dead zones, Stribeck, asymmetry)
``acceleration``  16 quantile bins of ddq_j (inertia-like)
``load``          16 quantile bins of the model's torque on the joint (load-dependent effects, saturation)
``time``          Legendre polynomials of time up to degree 4 (drift: temperature, sensor creep)
``periodic_t``    sin/cos(2 pi f t) at the 3 strongest spectral peaks below the filter cutoff (disturbances)
``step_drift``    a velocity-sign step whose height is a degree-4 polynomial of time (friction drifting with
                  temperature)
``step_pose``     a velocity-sign step whose height changes over 8 position bins (pose-dependent friction,
                  backlash against gravity)
================  ==========================================================================================

The cross-validation uses interleaved 1 s blocks (every fifth block held out in turn), so that time-dependent groups
are judged by interpolation, not extrapolation.

Besides the groups, a **slow-residual test** catches what no single variable of the joint describes (effects
coupling several joints, such as link inertial errors): the power of the low-passed residual (below the filter
cutoff) against what white noise at the floor leaves there (``noise^2 (1 - highpass_power_fraction)``); it
counts when it exceeds that by ``SLOW_Z`` standard deviations of its estimate (from its effective sample size)
and the slow RMS is at least ``SLOW_PRACTICAL`` noise floors. For logs slower than ``SLOW_MIN_RATE`` the torque's
faster content aliases into the slow band and the floor (estimated between the cutoff and the Nyquist frequency)
no longer predicts it: on correctly modelled logs at 30-100 Hz (three independent generators) up to about one noise
floor of slow residual remains. There the slow test counts only a slow residual of at least
``SLOW_PRACTICAL_LOW`` noise floors (a larger effect than the floor's own uncertainty can produce: a contact, a cable
spring, presliding friction, cogging or a disturbance leave 1.5-10 floors); smaller ones are reported, not
counted.

A group is *significant* on a joint when its held-out evidence
``N_eff ln(MSE0/MSE1) - k ln N_eff`` exceeds ``SCORE_MIN + ln(m)`` (``m`` the number of tests, a Bonferroni-like
correction for testing 10 groups on 7 joints and scanning frequencies; ``N_eff`` the effective sample size of the
residual, with or without the group, whichever is larger, under its autocorrelation) **and**
it removes an RMS of at least ``PRACTICAL`` times the joint's noise floor. ``explained`` is false when any group is
significant on any joint; the description says which joints, how large, and what the residual follows.
The tests run on the residual decimated to about 250 Hz (the motion is low-passed at 10 Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from franka_vs_gym.validation.effects import Context
from franka_vs_gym.validation.selection import n_eff
from franka_vs_gym.validation.signals import ProcessedLog

SCORE_MIN = 10.0
PRACTICAL = 0.2
N_BINS = 16
T_DEGREE = 4
K_MAX = 320  # cycles per turn scanned by periodic_q (strain-wave ripple at 2 x gear ratio)
BLOCK_S = 1.0  # s, length of the interleaved cross-validation blocks
SLOW_Z = 4.0  # standard deviations of the slow-power test (about 1e-4 per joint under white noise)
SLOW_PRACTICAL = 0.5  # slow residual RMS, in noise floors, below which nothing is reported
SLOW_MIN_RATE = 250.0  # Hz: below this log rate the slow test needs SLOW_PRACTICAL_LOW
SLOW_PRACTICAL_LOW = 1.25  # noise floors: slow residual counted below SLOW_MIN_RATE (the floor is uncertain there)
GROUPS = ("constant", "position", "periodic_q", "velocity", "acceleration", "load", "time", "periodic_t",
          "step_drift", "step_pose")
STEP_VEL = 0.02  # rad/s, smoothing of the velocity sign in the step groups
FOLLOWS = {"constant": "a constant offset", "position": "the joint position q", "periodic_q": "a periodic function "
           "of the joint position", "velocity": "the joint velocity dq", "acceleration": "the joint acceleration ddq",
           "load": "the joint's load torque", "time": "time (a drift)", "periodic_t": "a periodic disturbance in time",
           "step_drift": "a friction-like step whose height drifts over time",
           "step_pose": "a friction-like step whose height depends on the position",
           "slow": "time (slow residual that follows no single variable)",
           "lack_of_fit": "a shape of a selected effect's own variable that its law does not capture"}


@dataclass
class Finding:
    """A significant structure on one joint: the group, the RMS it removes (Nm), its score, and a detail (a period,
    a frequency)."""

    joint: int
    group: str
    removed_rms: float
    score: float
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"joint": self.joint, "follows": self.group, "removed_rms": round(self.removed_rms, 4),
                "score": round(self.score, 1), "detail": self.detail}


@dataclass
class Unexplained:
    """Result of :func:`test_structure`: ``explained``, the residual RMSE (7,) and noise floor (7,) Nm, the findings
    (all significant groups, strongest first per joint), a sentence per joint, and the x-values of each joint's
    strongest finding for the plot."""

    explained: bool
    rmse: np.ndarray
    noise: np.ndarray
    findings: list[Finding] = field(default_factory=list)
    text: list[str] = field(default_factory=list)
    plot_data: dict[int, tuple[str, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)

    @property
    def joints(self) -> list[int]:
        return sorted({f.joint for f in self.findings})

    def to_dict(self) -> dict[str, Any]:
        return {"joints": self.joints, "rmse_tau": np.round(self.rmse, 4).tolist(),
                "excess_rms": np.round(np.sqrt(np.maximum(self.rmse ** 2 - self.noise ** 2, 0.0)), 4).tolist(),
                "findings": [f.to_dict() for f in self.findings], "description": " ".join(self.text)}


def _bins(x: np.ndarray, n: int) -> np.ndarray:
    edges = np.quantile(x, np.linspace(0, 1, n + 1)[1:-1])
    return np.searchsorted(edges, x)


def _cv_bins(r: np.ndarray, b: np.ndarray, fold: np.ndarray, F: int, nb: int) -> np.ndarray:
    """Held-out prediction of r by bin means (bins b, trained on the other folds)."""
    out = np.zeros_like(r)
    s_all = np.bincount(b, r, nb)
    c_all = np.bincount(b, None, nb)
    for f in range(F):
        m = fold == f
        s = s_all - np.bincount(b[m], r[m], nb)
        c = c_all - np.bincount(b[m], None, nb)
        mean = np.where(c > 0, s / np.maximum(c, 1), 0.0)
        out[m] = mean[b[m]]
    return out


def _cv_lin(r: np.ndarray, X: np.ndarray, fold: np.ndarray, F: int) -> np.ndarray:
    out = np.zeros_like(r)
    A_all = X.T @ X
    b_all = X.T @ r
    for f in range(F):
        m = fold == f
        A = A_all - X[m].T @ X[m]
        b = b_all - X[m].T @ r[m]
        th = np.linalg.lstsq(A + 1e-9 * np.eye(len(b)) * max(np.trace(A), 1e-12), b, rcond=None)[0]
        out[m] = X[m] @ th
    return out


def _harmonics(x: np.ndarray, ks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """sin and cos (len(ks), len(x)) of 2 pi k x for every k of ``ks``. Equally spaced ``ks`` (the scan's) take the
    three-term recurrence s_(i+1) = 2 cos(d) s_i - s_(i-1) of the angle step d (one multiply-add per value instead of
    a sine and a cosine; it agrees with them to ~1e-11), others ``np.sin``/``np.cos``."""
    K = len(ks)
    step = np.diff(ks)
    if K < 3 or not np.allclose(step, step[0], rtol=1e-9, atol=0.0):
        w = np.outer(2 * math.pi * ks, x)
        return np.sin(w), np.cos(w)
    a = 2 * math.pi * ks[0] * x
    d = 2 * math.pi * (ks[1] - ks[0]) * x
    s, c = np.empty((K, len(x))), np.empty((K, len(x)))
    s[0], c[0], s[1], c[1] = np.sin(a), np.cos(a), np.sin(a + d), np.cos(a + d)
    c2 = 2.0 * np.cos(d)
    for i in range(2, K):
        np.multiply(c2, s[i - 1], out=s[i])
        s[i] -= s[i - 2]
        np.multiply(c2, c[i - 1], out=c[i])
        c[i] -= c[i - 2]
    return s, c


def _best_periodic(r: np.ndarray, x: np.ndarray, ks: np.ndarray) -> tuple[float, float]:
    """Frequency (cycles per unit of x, from ks) whose sin/cos explains most of r (least squares with intercept).
    All frequencies of a chunk at once (the 2x2 normal equations solved in closed form), chunks of at most about
    two million samples x frequencies."""
    ks = np.asarray(ks, dtype=np.float64)
    rc = r - r.mean()
    gains = np.empty(len(ks))
    step = max(3, int(2_000_000 // max(len(x), 1)))
    for i0 in range(0, len(ks), step):
        s, c = _harmonics(x, ks[i0:i0 + step])
        s -= s.mean(axis=1, keepdims=True)
        c -= c.mean(axis=1, keepdims=True)
        a11 = np.einsum("kn,kn->k", s, s) + 1e-12
        a12 = np.einsum("kn,kn->k", s, c)
        a22 = np.einsum("kn,kn->k", c, c) + 1e-12
        b1, b2 = s @ rc, c @ rc
        det = a11 * a22 - a12 * a12
        with np.errstate(divide="ignore", invalid="ignore"):
            g = ((a22 * b1 - a12 * b2) * b1 + (a11 * b2 - a12 * b1) * b2) / det
        gains[i0:i0 + step] = np.where(np.isfinite(g) & (det > 0), g, -np.inf)
    i = int(np.argmax(gains))
    if not gains[i] > -1.0:
        return float(ks[0]), -1.0
    return float(ks[i]), float(gains[i])


def test_structure(ctx: Context, residual: np.ndarray, noise: np.ndarray, folds: list[np.ndarray]) -> Unexplained:
    """Test the residual (N, 7) Nm of the selected model for structure (see the module docstring)."""
    data: ProcessedLog = ctx.data
    step = max(1, int(round(data.settings.rate / 250.0)))
    idx = np.arange(0, data.n, step)
    n = len(idx)
    F = len(folds)
    t = data.time[idx]
    # interleaved 1 s blocks (not contiguous fifths): a held-out block then has training data on both sides in
    # time, which the time-dependent groups need
    fold = (np.floor((t - t[0]) / BLOCK_S).astype(int)) % F
    rate = data.settings.rate / step
    ks_q = np.arange(1, K_MAX + 1) / (2 * math.pi)  # cycles per rad: k cycles per turn ... up to K_MAX per turn
    n_tests = 7 * (len(GROUPS) + len(ks_q) + 3)
    threshold = SCORE_MIN + math.log(n_tests)
    rm = np.sqrt(np.mean(residual ** 2, axis=0))
    findings: list[Finding] = []
    plot: dict[int, tuple[str, np.ndarray, np.ndarray, np.ndarray]] = {}
    tn = 2 * (t - t[0]) / max(t[-1] - t[0], 1e-9) - 1
    T = np.polynomial.legendre.legvander(tn, T_DEGREE)  # (n, 5), smooth in time: interpolates held-out blocks
    for j in range(7):
        r = residual[idx, j]
        ne_r = float(n_eff(r))
        ne = max(ne_r, 2.0)
        ln_ne = math.log(ne)
        mse0 = float(np.mean(r ** 2))
        cand: list[tuple[str, np.ndarray, int, str, np.ndarray]] = []
        # constant
        cand.append(("constant", _cv_lin(r, np.ones((n, 1)), fold, F), 1, "", t))
        for g, x in (("position", data.q[idx, j]), ("velocity", data.dq[idx, j]),
                     ("acceleration", data.ddq[idx, j]), ("load", ctx.ev.predicted[idx, j])):
            b = _bins(x, N_BINS)
            cand.append((g, _cv_bins(r, b, fold, F, N_BINS), N_BINS, "", x))
        cand.append(("time", _cv_lin(r, T, fold, F), T_DEGREE + 1, "", t))
        sgn = np.tanh(data.dq[idx, j] / STEP_VEL)
        cand.append(("step_drift", _cv_lin(r, sgn[:, None] * T, fold, F), T_DEGREE + 1, "", t))
        qb = _bins(data.q[idx, j], 8)
        X = sgn[:, None] * (qb[:, None] == np.arange(8)[None, :])
        cand.append(("step_pose", _cv_lin(r, X, fold, F), 8, "", data.q[idx, j]))
        q = data.q[idx, j]
        if np.ptp(q) > 0.05:
            k, _ = _best_periodic(r, q, ks_q)
            w = 2 * math.pi * k * q
            X = np.column_stack([np.ones(n), np.sin(w), np.cos(w)])
            cand.append(("periodic_q", _cv_lin(r, X, fold, F), 3,
                         f"period {1 / k:.3g} rad ({2 * math.pi * k:.0f} per turn)", q))
        # periodic in time: the strongest spectral peaks of the residual below the cutoff
        spec = np.abs(np.fft.rfft(r - r.mean())) ** 2
        freqs = np.fft.rfftfreq(n, 1.0 / rate)
        ok = (freqs > 2.0 / max(t[-1] - t[0], 1e-9)) & (freqs < data.settings.cutoff)
        if ok.any():
            peaks = np.argsort(np.where(ok, spec, 0.0))[-3:]
            best = None
            for p in peaks:
                fq = float(freqs[p])
                w = 2 * math.pi * fq * t
                X = np.column_stack([np.ones(n), np.sin(w), np.cos(w)])
                pred = _cv_lin(r, X, fold, F)
                m1 = float(np.mean((r - pred) ** 2))
                if best is None or m1 < best[0]:
                    best = (m1, pred, fq)
            cand.append(("periodic_t", best[1], 3, f"{best[2]:.3g} Hz", t))
        sig = []
        for g, pred, k, detail, x in cand:
            mse1 = float(np.mean((r - pred) ** 2))
            ne = max(ne_r, float(n_eff(r - pred)), 2.0)  # what remains once the group is removed
            ln_ne = math.log(ne)
            score = ne * math.log(max(mse0, 1e-30) / max(mse1, 1e-30)) - k * ln_ne
            removed = math.sqrt(max(mse0 - mse1, 0.0))
            if score > threshold and removed >= PRACTICAL * noise[j]:
                sig.append((removed, score, g, detail, x))
        sig.sort(key=lambda s: -s[0])
        for removed, score, g, detail, _x in sig:
            findings.append(Finding(j, g, removed, score, detail))
        if sig:
            g, x = sig[0][2], sig[0][4]
            plot[j] = (g, x, r, np.full(1, noise[j]))
    # slow residual: the low-passed residual's power against what white noise at the floor leaves below the cutoff
    from scipy import signal as sps

    from franka_vs_gym.validation.signals import highpass_power_fraction

    sos = sps.butter(data.settings.order, data.settings.cutoff, fs=data.settings.rate, output="sos")
    lf = sps.sosfiltfilt(sos, residual, axis=0)
    expected = noise ** 2 * max(1.0 - highpass_power_fraction(data.settings), 1e-6)
    p_lf = np.mean(lf ** 2, axis=0)
    ne_lf = np.maximum(np.asarray(n_eff(lf)), 2.0)
    slow = np.sqrt(np.maximum(p_lf - expected, 0.0))
    slow_sig = (p_lf > expected * (1 + SLOW_Z * np.sqrt(2.0 / ne_lf))) & (slow >= SLOW_PRACTICAL * noise)
    raw_rate = 1.0 / data.report.dt_median if data.report.dt_median > 0 else data.settings.rate
    low_rate_note = None
    if raw_rate < SLOW_MIN_RATE and slow_sig.any():
        # below ~250 Hz the torque's faster content aliases into the band below the cutoff: the floor estimated
        # above the cutoff no longer predicts the slow band, so only a slow residual larger than that uncertainty
        # counts
        weak = slow_sig & (slow < SLOW_PRACTICAL_LOW * noise)
        if weak.any():
            low_rate_note = (f"joints {np.nonzero(weak)[0].tolist()} keep {np.round(slow[weak], 3).tolist()} Nm of "
                             f"slow residual above the noise floor; at {raw_rate:.0f} Hz the floor estimate does not "
                             f"cover aliased content, so less than {SLOW_PRACTICAL_LOW:g} noise floors of it is not "
                             "counted as unexplained")
        slow_sig &= ~weak
    for j in np.nonzero(slow_sig)[0]:
        if not any(f.joint == j for f in findings):
            findings.append(Finding(int(j), "slow", float(slow[j]), 0.0, "follows no single variable of this joint"))
            plot[int(j)] = ("slow", data.time[idx], residual[idx, j], np.full(1, noise[j]))
    text = []
    for j in sorted({f.joint for f in findings}):
        fj = [f for f in findings if f.joint == j]
        excess = math.sqrt(max(rm[j] ** 2 - noise[j] ** 2, 0.0))
        main = fj[0]
        if main.group == "slow":
            text.append(f"joint {j}: {excess:.3g} Nm RMS above the noise floor ({noise[j]:.3g} Nm), {slow[j]:.3g} Nm "
                        "of it slow (below the filter cutoff); it follows no single variable of this joint (q, dq, "
                        "ddq, load, time): an effect coupling several joints (e.g. link inertial errors) or "
                        "coloured noise.")
            continue
        s = (f"joint {j}: {excess:.3g} Nm RMS above the noise floor ({noise[j]:.3g} Nm); it follows "
             f"{FOLLOWS[main.group]}{' (' + main.detail + ')' if main.detail else ''} ({main.removed_rms:.3g} Nm)")
        if len(fj) > 1:
            s += "; also " + ", ".join(f"{FOLLOWS[f.group]} ({f.removed_rms:.3g} Nm)" for f in fj[1:3])
        text.append(s + ".")
    explained = not findings
    if explained:
        text.append("No structure left in the residual that the tests can see." if low_rate_note else
                    "The residual is at the noise floor on every joint: nothing left to explain.")
    if low_rate_note:
        text.append(low_rate_note + ".")
    return Unexplained(explained, rm, noise.copy(), findings, text, plot)


def assumptions_of(data: ProcessedLog, config: Any, tool: str | None = None) -> dict[str, Any]:
    """What the result assumes, for every output: tool, gravity, rate, cleaning, and warnings about the data."""
    log = data.log
    rep = data.report
    if tool is not None:
        tool_src = f"--tool {tool}" + (" (mass, centre of mass and inertia fitted as a payload)"
                                       if tool == "unknown" else "")
    elif log.tool_declared:
        tool_src = "declared by the log" + (f" ({log.extra['tool_source']})" if log.extra.get("tool_source") else "")
        said = log.extra.get("tool_declared_as")
        if log.extra.get("tool_source") == "--tool":  # read with --tool: the log's own declaration overridden
            tool_src = "--tool" + (f" (the log's {said!r} overridden)" if isinstance(said, str) else "")
        elif isinstance(said, str):  # named in words: what it said, as it was read
            tool_src += f" as {said!r}"
    elif getattr(config, "notes", {}).get("tool_estimate"):
        tool_src = config.notes["tool_estimate"]
    else:
        tool_src = "not declared by the log: the Franka Hand assumed (use --tool to say otherwise)"
    raw_rate = 1.0 / rep.dt_median if rep.dt_median > 0 else float("nan")
    out = {"robot": config.robot.name, "robot_source": getattr(config, "notes", {}).get("robot_source", "not stated"),
           "tool": config.tool.name if hasattr(config.tool, "name") else str(config.tool),
           "tool_mass_kg": round(float(config.tool.body.mass), 4), "tool_source": tool_src,
           "gravity_m_per_s2": np.round(config.gravity, 4).tolist(),
           "log_rate_hz": round(raw_rate, 2), "resampled_to_hz": data.settings.rate,
           "cleaning": {"stale_rows_dropped": rep.stale_rows, "repeated_timestamps_dropped": rep.repeated_timestamps,
                        "lowpass_hz": data.settings.cutoff, "filter": f"Butterworth order {data.settings.order}, "
                                                                        "zero phase", "trim_s": data.settings.trim,
                        "max_gap_s": rep.settings.get("max_gap_used", data.settings.max_gap),
                        "acceleration": ("central difference of the filtered velocity"
                                         if data.settings.derivative == "central" else
                                         "derivative of the cubic spline through the filtered velocity"),
                        "resampling": "linear interpolation onto a uniform grid"},
           "samples": int(data.n), "duration_s": round(float(data.n / data.settings.rate), 3),
           "warnings": list(getattr(rep, "warnings", []))}
    if log.extra.get("read_as"):  # how a foreign dump was read (format, time unit)
        out["log_read_as"] = log.extra["read_as"]
    return out


__all__ = ["Finding", "Unexplained", "assumptions_of", "test_structure"]
