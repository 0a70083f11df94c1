"""Cleaning a raw measurement log: stale rows, irregular timestamps, resampling, zero-phase filtering, derivatives.

Stated choices (all in :class:`CleanSettings`, reported in :class:`CleaningReport`):

1. **Stale rows.** A row whose q, dq and tau_J are bit-identical to the previous row is a sample the robot did not
   refresh (the Gaz et al. logs hold about 1100 of them); it is dropped, as are rows repeating the previous
   timestamp (the first is kept).
2. **Resampling.** The remaining samples are linearly interpolated onto a uniform grid at ``rate`` (1 kHz by
   default) spanning the log. Gaps longer than ``max_gap`` (50 ms) are reported as an error: interpolating over
   them would invent motion.
3. **Filtering.** q, dq (and the optional desired signals) are low-passed with a Butterworth filter of order
   ``order`` (4) at ``cutoff`` (10 Hz), applied forward and backward (zero phase, so no time shift between torque
   and motion is introduced). ``tau_J`` is kept unfiltered for the error statistics (RMSE is quoted against the raw
   measurement, as in Gaz et al. 2019); a filtered copy is kept for plots.
4. **Derivatives.** ddq is the central difference of the filtered measured dq (the robot's own velocity is less
   noisy than differentiated positions).
5. **Noise floor.** The torque measurement noise per joint is the RMS of ``tau_J - lowpass(tau_J)`` (the content
   above the cutoff), divided by the fraction of white-noise power the high-pass keeps (computed from the filter's
   frequency response). It is what the inverse-dynamics residual can at best fall to.

Nothing here modifies the input log.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import signal

from franka_vs_gym.validation.logs import OPTIONAL, MeasurementLog


@dataclass(frozen=True)
class CleanSettings:
    """Cleaning parameters: rate (Hz) of the uniform grid, cutoff (Hz) and order of the zero-phase Butterworth
    low-pass, max_gap (s) the longest gap interpolated over, trim (s) cut at each end after filtering (edge
    effects of the filter and of the derivative)."""

    rate: float = 1000.0
    cutoff: float = 10.0
    order: int = 4
    max_gap: float = 0.05
    trim: float = 0.3

    def __post_init__(self) -> None:
        if not self.rate > 0:
            raise ValueError(f"rate must be > 0 Hz, got {self.rate}")
        if not 0 < self.cutoff < self.rate / 2:
            raise ValueError(f"cutoff must be in (0, rate/2) = (0, {self.rate / 2}) Hz, got {self.cutoff}")
        if self.order < 1:
            raise ValueError(f"order must be >= 1, got {self.order}")


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
                            self.log, self.report, self.settings)


def _lowpass(settings: CleanSettings):
    return signal.butter(settings.order, settings.cutoff, fs=settings.rate, output="sos")


def highpass_power_fraction(settings: CleanSettings) -> float:
    """Fraction of white-noise power left in ``x - filtfilt(x)`` (from the frequency response)."""
    sos = _lowpass(settings)
    _, h = signal.sosfreqz(sos, worN=8192, fs=settings.rate)
    h2 = np.abs(h) ** 2  # filtfilt: magnitude squared, zero phase
    return float(np.mean((1.0 - h2) ** 2))


def clean(log: MeasurementLog, settings: CleanSettings | None = None) -> ProcessedLog:
    """Clean, resample, filter and differentiate a log (see the module docstring). Returns a new object."""
    s = settings or CleanSettings()
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
    gap = float(dts.max())
    if gap > s.max_gap:
        i = int(np.argmax(dts))
        raise ValueError(f"log has a {gap * 1000:.1f} ms gap at t = {t[i]:.4f} s (longer than max_gap "
                         f"{s.max_gap * 1000:.0f} ms): split the log there")
    raw_dt = np.diff(t_raw)
    raw_dt = raw_dt[raw_dt > 0]
    grid = np.arange(t[0], t[-1] + 0.5 / s.rate, 1.0 / s.rate)
    grid = grid[grid <= t[-1]]
    min_len = int(2 * s.trim * s.rate) + 3 * (s.order * 6)
    if len(grid) <= min_len:
        raise ValueError(f"log too short: {t[-1] - t[0]:.3f} s; need more than {min_len / s.rate:.2f} s")

    def resample(a: np.ndarray) -> np.ndarray:
        out = np.empty((len(grid), a.shape[1]))
        for j in range(a.shape[1]):
            out[:, j] = np.interp(grid, t, a[keep, j])
        return out

    sos = _lowpass(s)

    def lp(a: np.ndarray) -> np.ndarray:
        return signal.sosfiltfilt(sos, a, axis=0)

    q = lp(resample(log.q))
    dq = lp(resample(log.dq))
    ddq = np.gradient(dq, 1.0 / s.rate, axis=0)
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
    frac = highpass_power_fraction(s)
    hf = (tau - tau_filt)[sl]
    noise = np.sqrt(np.mean(hf ** 2, axis=0) / frac)
    report = CleaningReport(n_in, int(stale.sum()), int(rep.sum()), float(raw_dt.min()), float(np.median(raw_dt)),
                            float(raw_dt.max()), int(sl.stop - sl.start), asdict(s))
    return ProcessedLog(grid[sl] - grid[0], q[sl], dq[sl], ddq[sl], tau[sl], tau_filt[sl],
                        {kk: v[sl] for kk, v in optional.items()}, noise, log, report, s)


__all__ = ["CleanSettings", "CleaningReport", "ProcessedLog", "clean", "highpass_power_fraction"]
