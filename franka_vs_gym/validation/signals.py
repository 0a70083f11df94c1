"""Cleaning a raw measurement log: stale rows, irregular timestamps, resampling, zero-phase filtering, derivatives.

Stated choices (all in :class:`CleanSettings`, reported in :class:`CleaningReport`):

1. **Stale rows.** A row whose q, dq and tau_J are bit-identical to the previous row is a sample the robot did not
   refresh (the Gaz et al. logs hold about 1100 of them); it is dropped, as are rows repeating the previous
   timestamp (the first is kept).
2. **Resampling.** The remaining samples are linearly interpolated onto a uniform grid at ``rate`` (by default the
   log's own median rate, at most 1 kHz: a 30 Hz ROS log stays at 30 Hz, nothing is invented between its samples)
   spanning the log. Gaps are judged relative to the log's own rate: longer than ``max_gap`` (by default 4 median
   sample periods, at least 50 ms) is an error (interpolating over them would invent motion); shorter gaps are
   bridged and counted in the report's warnings.
3. **Filtering.** q, dq (and the optional desired signals) are low-passed with a Butterworth filter of order
   ``order`` (4) at ``cutoff`` (10 Hz, or a quarter of the rate for logs slower than 40 Hz), applied forward and
   backward (zero phase, so no time shift between torque and motion is introduced). ``tau_J`` is kept unfiltered
   for the error statistics (RMSE is quoted against the raw measurement, as in Gaz et al. 2019); a filtered copy is
   kept for plots.
4. **Derivatives.** ddq is the derivative of the filtered measured dq (the robot's own velocity is less noisy than
   differentiated positions): the central difference where it is exact to 0.1 % up to the cutoff (1 kHz logs),
   else the derivative of the cubic spline through the samples, exact to 3e-4 at a fifteenth of the rate, where the
   central difference loses 3 % (see ``DERIVATIVES``). The white noise the measured velocity
   carries (its content above the cutoff) and the noise it puts into ddq are estimated (``ddq_noise``).
5. **Noise floor.** The torque measurement noise per joint is the RMS of ``tau_J - lowpass(tau_J)`` (the content
   above the cutoff), divided by the fraction of white-noise power the high-pass keeps (computed from the filter's
   frequency response). It is what the inverse-dynamics residual can at best fall to.

Nothing here modifies the input log.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import signal

from franka_vs_gym.validation.logs import OPTIONAL, Q_RANGE_WARN, MeasurementLog, joint_range

MAX_RATE = 1000.0  # Hz: logs faster than this are resampled down to it
MAX_USER_RATE = 10_000.0  # Hz: the highest --rate accepted (10x the FER's state rate)
MIN_CUTOFF = 0.1  # Hz: the lowest --cutoff accepted (below it the filter removes the motion, and goes singular)
GAP_FACTOR = 4.0  # default max_gap: this many of the log's own median sample periods (at least 50 ms)
#: the smallest torque noise floor used, Nm: a noise-free (simulated) log has an estimated floor near 0, while the
#: processing itself leaves errors of up to about 1e-3 Nm (acceleration from the filtered velocity, resampling; the
#: exact model's residual on `franka-vs experiment tracking --torque-noise 0`): effects are judged against at least
#: this floor, 3x below the lowest real FER floor seen (0.027 Nm, joint 6 of the Gaz et al. 2019 log)
NOISE_FLOOR_MIN = 0.01
MIN_SECONDS = 3.0  # shortest log (after trimming) a diagnosis is attempted on


@dataclass(frozen=True)
class CleanSettings:
    """Cleaning parameters: rate (Hz) of the uniform grid (None: the log's own median rate, at most 1 kHz), cutoff
    (Hz) and order of the zero-phase Butterworth low-pass (cutoff None: 10 Hz, or a quarter of the rate for slower
    logs), max_gap (s) the longest gap interpolated over (None: ``GAP_FACTOR`` median sample periods of the log, at
    least 50 ms), trim (s) cut at each end after filtering (edge effects of the filter and of the derivative)."""

    rate: float | None = None
    cutoff: float | None = None
    order: int = 4
    max_gap: float | None = None
    trim: float = 0.3
    derivative: str = "auto"

    def __post_init__(self) -> None:
        if self.derivative not in DERIVATIVES:
            raise ValueError(f"derivative must be one of {', '.join(DERIVATIVES)}, got {self.derivative!r}")
        if self.rate is not None and not self.rate > 0:
            raise ValueError(f"rate must be > 0 Hz, got {self.rate}")
        if self.rate is not None and self.rate > MAX_USER_RATE:
            raise ValueError(f"rate {self.rate:g} Hz is above {MAX_USER_RATE:g} Hz (the FER's state comes at 1 kHz; a "
                             "finer grid only interpolates)")
        if self.cutoff is not None and not self.cutoff > 0:
            raise ValueError(f"cutoff must be > 0 Hz, got {self.cutoff}")
        if self.cutoff is not None and self.cutoff < MIN_CUTOFF:
            raise ValueError(f"cutoff {self.cutoff:g} Hz is below {MIN_CUTOFF:g} Hz: such a low-pass removes the "
                             "motion itself (the default is 10 Hz)")
        if self.rate is not None and self.cutoff is not None and not self.cutoff < self.rate / 2:
            raise ValueError(f"cutoff must be in (0, rate/2) = (0, {self.rate / 2}) Hz, got {self.cutoff}")
        if self.max_gap is not None and not self.max_gap > 0:
            raise ValueError(f"max_gap must be > 0 s, got {self.max_gap}")
        if self.order < 1:
            raise ValueError(f"order must be >= 1, got {self.order}")

    def resolved(self, raw_dt: float) -> CleanSettings:
        """The settings with the automatic values fixed for a log whose median sample period is raw_dt (s)."""
        from dataclasses import replace

        raw_rate = 1.0 / raw_dt
        rate = self.rate if self.rate is not None else min(MAX_RATE, float(round(raw_rate)))
        cutoff = self.cutoff if self.cutoff is not None else min(10.0, 0.25 * min(rate, raw_rate))
        if not cutoff < rate / 2:
            raise ValueError(f"cutoff {cutoff} Hz must be below half the rate ({rate / 2} Hz)")
        max_gap = self.max_gap if self.max_gap is not None else max(0.05, GAP_FACTOR * raw_dt)
        der = self.derivative
        if der == "auto":  # the central difference where it is exact to 0.1 % up to the cutoff, else the spline's
            x = 2 * np.pi * cutoff / rate
            der = "central" if np.sin(x) / x >= 1.0 - CENTRAL_TOL else "spline"
        return replace(self, rate=rate, cutoff=cutoff, max_gap=max_gap, derivative=der)


@dataclass
class CleaningReport:
    """What cleaning did: rows in, stale rows and repeated timestamps dropped, raw time-step statistics (s)."""

    rows_in: int
    stale_rows: int
    repeated_timestamps: int
    dt_min: float
    dt_median: float
    dt_max: float
    samples_out: int
    settings: dict[str, Any] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    gaps_bridged: int = 0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class ProcessedLog:
    """A log on a uniform time grid, ready for model evaluation.

    time (N,) s from the first sample; q, dq, ddq (N, 7) filtered (rad, rad/s, rad/s^2); tau (N, 7) raw measured
    tau_J resampled (Nm); tau_filt (N, 7) its low-passed copy; optional (N, 7) fields resampled (desired signals
    filtered, tau_J_d raw); noise (7,) Nm the estimated torque-noise standard deviation; the source log's
    metadata; the cleaning report.
    """

    time: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray
    tau_filt: np.ndarray
    optional: dict[str, np.ndarray]
    noise: np.ndarray
    log: MeasurementLog
    report: CleaningReport
    settings: CleanSettings
    #: (7,) rad/s^2 standard deviation of the noise in ddq that comes from the measured velocity's white noise (its
    #: content above the cutoff, scaled like the torque noise floor, through the low-pass and the derivative);
    #: None when not estimated
    ddq_noise: np.ndarray | None = None
    #: the equivalent degrees of freedom of ``ddq_noise``'s variance (a chi-square estimate from the periodogram)
    ddq_noise_dof: float = math.inf

    @property
    def n(self) -> int:
        return len(self.time)

    @property
    def dt(self) -> float:
        return 1.0 / self.settings.rate

    def subset(self, idx: np.ndarray) -> ProcessedLog:
        """The samples at indices ``idx`` (a copy; the time grid may become non-uniform)."""
        return ProcessedLog(self.time[idx], self.q[idx], self.dq[idx], self.ddq[idx], self.tau[idx],
                            self.tau_filt[idx], {k: v[idx] for k, v in self.optional.items()}, self.noise,
                            self.log, self.report, self.settings, self.ddq_noise,
                            self.ddq_noise_dof)



#: how ddq is taken from the filtered dq: "spline" the derivative of the cubic spline through the samples (gain
#: 3 sin x / (x (2 + cos x)), x = 2 pi f / rate: 0.9997 at 2 Hz in a 30 Hz log), "central" the central difference
#: (gain sin x / x: 0.971 at 2 Hz in a 30 Hz log, which leaves 3 % of M(q) ddq in the residual, absorbed by the
#: armature), "auto" the central difference where its gain at the cutoff is within CENTRAL_TOL of 1 (1 kHz with the
#: 10 Hz cutoff: 0.99934; the two differ by 3e-5 of ddq there) and the spline's below (100 Hz: 0.935, 30 Hz: 0.64)
DERIVATIVES = ("auto", "spline", "central")
CENTRAL_TOL = 1e-3


def derivative(x: np.ndarray, rate: float, method: str = "spline") -> np.ndarray:
    """The time derivative of x (N, ...) sampled uniformly at ``rate`` Hz, along axis 0 ("spline" or "central";
    see ``DERIVATIVES``)."""
    h = 1.0 / rate
    if method == "central":
        return np.gradient(x, h, axis=0)
    if method == "spline":
        from scipy.interpolate import CubicSpline

        t = np.arange(len(x)) * h
        return CubicSpline(t, x, axis=0)(t, 1)
    raise ValueError(f"unknown derivative {method!r}")


def ddq_noise_gain(settings: CleanSettings) -> float:
    """Standard deviation (rad/s^2) of the acceleration ``clean`` makes from a velocity carrying white noise of 1
    rad/s at the settings' rate: the root sum of squares of the impulse response of the zero-phase low-pass followed
    by the derivative."""
    rate, cutoff = settings.rate, settings.cutoff
    half = min(int(np.ceil(40 * rate / cutoff)), 200_000)  # the low-pass's impulse response has died out by then
    x = np.zeros(2 * half + 1)
    x[half] = 1.0
    h = derivative(signal.sosfiltfilt(_lowpass(settings), x), rate, settings.derivative)
    return float(np.sqrt(np.sum(h[half // 2: -(half // 2)] ** 2)))


def velocity_noise_level(hf: np.ndarray, settings: CleanSettings) -> tuple[np.ndarray, float]:
    """(7,) the standard deviation of the white noise whose power spectral density ``hf`` (N, 7), the velocity's
    content above the cutoff (``dq - lowpass(dq)``), shows just above the cutoff (from the cutoff to 4 times it,
    below half the rate; least squares of the Welch periodogram on the complementary high-pass's power response),
    and the estimate's equivalent degrees of freedom (Hann segments overlapping by half: 1.89 per segment and
    independent bin, a bin being 1.5 of the periodogram's). The level there, unlike the RMS of all of ``hf``: a
    1 kHz velocity differentiated from an encoder has most of its noise at hundreds of Hz and little near 10 Hz,
    while at 30 Hz the same noise is folded flat over the whole band."""
    rate, fc = settings.rate, settings.cutoff
    nper = int(min(len(hf), max(16, 2 ** int(np.ceil(np.log2(4 * rate / fc))))))
    f, p = signal.welch(hf, fs=rate, nperseg=nper, axis=0, detrend=False)
    band = (f >= fc) & (f <= 4.0 * fc) & (f < 0.5 * rate)  # (the Nyquist bin of a one-sided PSD is not doubled)
    _, h = signal.sosfreqz(_lowpass(settings), worN=f[band], fs=rate)
    keep = (1.0 - np.abs(h) ** 2) ** 2  # the power the complementary high-pass of the zero-phase filter keeps
    level = keep @ p[band] / max(float(keep @ keep), 1e-12)  # one-sided PSD, (rad/s)^2 / Hz
    segments = max(1, (len(hf) - nper) // (nper // 2) + 1)
    bins = float(keep.sum() ** 2 / max(float(keep @ keep), 1e-12))
    return np.sqrt(np.maximum(level, 0.0) * rate / 2.0), max(1.89 * segments * bins / 1.5, 1.0)


def _lowpass(settings: CleanSettings):
    return signal.butter(settings.order, settings.cutoff, fs=settings.rate, output="sos")


def band_sos(settings: CleanSettings, n: int):
    """The cleaning's zero-phase low-pass (second-order sections) for taking the motion band of ``n`` samples, or
    None where it does not apply (no resolved rate or cutoff, a cutoff not below the Nyquist frequency, or too few
    samples for the filter's edges)."""
    st = settings
    if st.rate and st.cutoff and st.cutoff < st.rate / 2 and n > 6 * (st.order + 1) * 3:
        return _lowpass(st)
    return None


def highpass_power_fraction(settings: CleanSettings) -> float:
    """Fraction of white-noise power left in ``x - filtfilt(x)`` (from the frequency response); automatic
    settings are taken at 1 kHz."""
    if settings.rate is None or settings.cutoff is None or settings.max_gap is None:
        settings = settings.resolved(1.0 / (settings.rate or MAX_RATE))
    sos = _lowpass(settings)
    _, h = signal.sosfreqz(sos, worN=8192, fs=settings.rate)
    h2 = np.abs(h) ** 2  # filtfilt: magnitude squared, zero phase
    return float(np.mean((1.0 - h2) ** 2))


def clean(log: MeasurementLog, settings: CleanSettings | None = None) -> ProcessedLog:
    """Clean, resample, filter and differentiate a log (see the module docstring). Returns a new object."""
    s0 = settings or CleanSettings()
    t_raw = log.time
    n_in = len(t_raw)
    stale = np.zeros(n_in, dtype=bool)
    same = (log.q[1:] == log.q[:-1]).all(axis=1) & (log.dq[1:] == log.dq[:-1]).all(axis=1) & \
        (log.tau_J[1:] == log.tau_J[:-1]).all(axis=1)
    stale[1:] = same
    rep = np.zeros(n_in, dtype=bool)
    rep[1:] = np.diff(t_raw) == 0
    rep &= ~stale
    keep = ~(stale | rep)
    t = t_raw[keep]
    if len(t) < 10:
        raise ValueError(f"log has only {len(t)} distinct samples after dropping stale rows; need at least 10")
    dts = np.diff(t)
    raw_dt = np.diff(t_raw)
    raw_dt = raw_dt[raw_dt > 0]
    med = float(np.median(raw_dt))
    s = s0.resolved(med)
    gap = float(dts.max())
    if gap > s.max_gap:
        i = int(np.argmax(dts))
        raise ValueError(f"log has a {gap * 1000:.1f} ms gap at t = {t[i]:.4f} s, longer than max_gap "
                         f"{s.max_gap * 1000:.0f} ms ({s.max_gap / med:.1f} of its median sample periods of "
                         f"{med * 1000:.1f} ms): split the log there, or allow it with --max-gap")
    warnings: list[str] = []
    bridged = int(np.sum(dts > 1.5 * med))
    if bridged:
        warnings.append(f"{bridged} gaps longer than 1.5 sample periods (up to {gap * 1000:.1f} ms) were bridged by "
                        "linear interpolation")
    raw_rate = 1.0 / med
    if raw_rate < 250:
        warnings.append(f"the log's rate is {raw_rate:.0f} Hz: motion is low-passed at {s.cutoff:g} Hz and the "
                        f"acceleration is the derivative of a velocity sampled every {med * 1000:.0f} ms, so "
                        "inertial effects (armature, payload inertia) are poorly identifiable and a delay "
                        f"shorter than the {med * 1000:.0f} ms period is seen only where the torque changes fast")
    jitter = float(np.std(raw_dt) / med)
    if jitter > 0.05:
        warnings.append(f"irregular time stamps (sample period {med * 1000:.2f} ms +- {jitter * 100:.0f}%): "
                        "resampled by linear interpolation onto a uniform grid")
    grid = np.arange(t[0], t[-1] + 0.5 / s.rate, 1.0 / s.rate)
    grid = grid[grid <= t[-1]]
    min_len = int(2 * s.trim * s.rate) + 3 * (s.order * 6)
    if len(grid) <= min_len:
        raise ValueError(f"log too short: {t[-1] - t[0]:.3f} s; need more than {min_len / s.rate:.2f} s")
    if t[-1] - t[0] - 2 * s.trim < MIN_SECONDS:
        warnings.append(f"short log: {t[-1] - t[0]:.1f} s; results on less than {MIN_SECONDS + 2 * s.trim:.1f} s "
                        "are unreliable")

    def resample(a: np.ndarray) -> np.ndarray:
        out = np.empty((len(grid), a.shape[1]))
        for j in range(a.shape[1]):
            out[:, j] = np.interp(grid, t, a[keep, j])
        return out

    sos = _lowpass(s)

    def lp(a: np.ndarray) -> np.ndarray:
        return signal.sosfiltfilt(sos, a, axis=0)

    q = lp(resample(log.q))
    dq_res = resample(log.dq)
    dq = lp(dq_res)
    ddq = derivative(dq, s.rate, s.derivative)
    tau = resample(log.tau_J)
    tau_filt = lp(tau)
    optional = {}
    for name in OPTIONAL:
        a = getattr(log, name)
        if a is not None:
            r = resample(a)
            optional[name] = r if name in ("tau_J_d", "tau_ext_hat_filtered") else lp(r)
    k = int(round(s.trim * s.rate))
    sl = slice(k, len(grid) - k)
    still = [j for j in range(7) if np.abs(dq[sl, j]).max() < 0.05]
    if still:
        warnings.append(f"joints {still} barely move (abs(dq) < 0.05 rad/s): their friction, inertia and delay cannot "
                        "be identified from this log (only offsets and pose-dependent effects)")
    lo, hi = joint_range()
    beyond = np.maximum(lo - log.q, log.q - hi).max(axis=0)
    far = [j for j in range(7) if beyond[j] > Q_RANGE_WARN]
    if far:
        warnings.append("joint positions beyond every registered robot's range on joints "
                        + ", ".join(f"{j} (by {beyond[j]:.3g} rad)" for j in far)
                        + ": an encoder offset, another robot, or the joint columns in another order?")
    frac = highpass_power_fraction(s)
    hf = (tau - tau_filt)[sl]
    noise = np.sqrt(np.mean(hf ** 2, axis=0) / frac)
    low = [j for j in range(7) if noise[j] < NOISE_FLOOR_MIN]
    if low:
        warnings.append(f"torque noise floor estimated below {NOISE_FLOOR_MIN:g} Nm on joints {low} "
                        f"({', '.join(f'{noise[j]:.2g}' for j in low)} Nm; a noise-free log?): {NOISE_FLOOR_MIN:g} "
                        "Nm used there, the smallest error the processing resolves")
        noise = np.maximum(noise, NOISE_FLOOR_MIN)
    # the measured velocity's noise (its content above the cutoff, as for the torque) and what the derivative makes
    # of it: at low rates the velocity's broadband noise (a differentiated encoder) is folded into the log's band and
    # its derivative is an error in the regressor of every inertial effect (see uncertainty.inertial_bias)
    dq_level, ddq_noise_dof = velocity_noise_level(dq_res[sl] - dq[sl], s)
    ddq_noise = dq_level * ddq_noise_gain(s)
    report = CleaningReport(n_in, int(stale.sum()), int(rep.sum()), float(raw_dt.min()), float(np.median(raw_dt)),
                            float(raw_dt.max()), int(sl.stop - sl.start), asdict(s), warnings, bridged)
    return ProcessedLog(grid[sl] - grid[0], q[sl], dq[sl], ddq[sl], tau[sl], tau_filt[sl],
                        {kk: v[sl] for kk, v in optional.items()}, noise, log, report, s, ddq_noise,
                        ddq_noise_dof)


MAX_EFFECT_SAMPLES = 60_000  # samples the effect library works on (60 s at 1 kHz); longer logs are decimated


def decimated(data: ProcessedLog, max_samples: int = MAX_EFFECT_SAMPLES) -> ProcessedLog:
    """``data`` decimated by the smallest integer factor that leaves at most ``max_samples`` samples, keeping the
    rate above 4 times the low-pass cutoff (the motion signals are filtered, so nothing of them is lost; the
    torque noise averages over fewer samples). Returns ``data`` itself when no decimation is needed. Used by the
    effect library (its regressors take 70 columns per joint and sample) on long logs."""
    k = -(-data.n // max_samples)
    k = min(k, max(1, int(data.settings.rate // (4 * data.settings.cutoff))))
    if k <= 1:
        return data
    from dataclasses import replace

    idx = np.arange(0, data.n, k)
    sub = data.subset(idx)
    sub.settings = replace(data.settings, rate=data.settings.rate / k)
    return sub


__all__ = ["CleanSettings", "DERIVATIVES", "ddq_noise_gain", "derivative", "MAX_EFFECT_SAMPLES", "NOISE_FLOOR_MIN",
           "decimated", "CleaningReport", "ProcessedLog", "clean", "highpass_power_fraction", "velocity_noise_level"]
