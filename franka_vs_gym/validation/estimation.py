"""One noise model per log, and the estimate of any linear-in-parameters set of effect columns under it.

The residual torque of a log, ``e(t)`` (N, 7) Nm, is modelled as a stationary Gaussian vector process with a 7x7
cross-spectral matrix ``P(f)`` that is smooth in frequency: coloured (the filtered, differentiated acceleration in the
regressors, the robot's own unmodelled dynamics and the torque sensor's noise all have their own spectra) and
correlated across joints (the inertia matrix couples the joints' errors). ``P`` is estimated once per log from the
residual of a generous reference fit (:func:`noise_model`, :meth:`NoiseModel.from_reference`): the cross-periodogram
``I_k = d_k d_k^H`` of the residual's discrete Fourier transform ``d_k = sum_t e_t exp(-2 pi i k t / N) / sqrt(N)``,
averaged over ``2 m + 1`` neighbouring bins (a Daniell smoother; the edges reflected as the spectrum of a real series
is), and held fixed for every later comparison.

Under it, the frequency-domain (Whittle) Gaussian log-likelihood of a set of effect columns ``A`` (N, 7, p) with
parameters ``theta`` in the bins of a band (:meth:`NoiseModel.fit`) is

    l(theta) = - sum_{0 < k < N/2} [ log det(pi P_k) + r_k^H P_k^-1 r_k ]
               - 1/2 sum_{k in {0, N/2}} [ log det(2 pi P_k) + r_k^T P_k^-1 r_k ],   r_k = Y_k - A_k theta

(the transforms ``d_k`` of a stationary series are nearly independent across bins, complex Gaussian with covariance
``P_k`` inside the spectrum, real at 0 and N/2). Its maximiser is the feasible generalised least-squares estimate
``theta = M^-1 b`` with ``M = sum_k c_k Re(A_k^H P_k^-1 A_k)``, ``b = sum_k c_k Re(A_k^H P_k^-1 Y_k)`` (``c_k = 2``
inside the spectrum, 1 at its real bins), its covariance is ``M^-1``, and the maximum log-likelihood of different
column sets under the same noise model is comparable: the criterion of a selection can be built on it.

Only the bins of the band are used (a band-limited Whittle likelihood: the estimate is that of the band-passed log),
so a 30 s log at 1 kHz with a 20 Hz band gives about 600 bins x 7 joints and every later fit is small. A torque
offset lives at 0 Hz: keep 0 in the band when offsets are among the columns.

What this module does not model: errors in the regressors beyond what the reference fit's residual carries (the
residual holds ``A_err theta_ref`` at the reference parameters, to first order), and the deflation of the residual's
spectrum where the reference fit's columns concentrate (the fit removes the noise along its own columns). Measured
on simulated per-joint AR(1) noise (coefficients up to 0.97, correlated across joints; tests/test_estimation.py):
with the true spectrum the covariance matches the Monte Carlo spread (ratios 0.97-1.07); estimated from the
reference residual and smoothed over 65 bins the spread is 1.06-1.37 times the stated error (95 % intervals cover
84-95 %, 90 % overall), the worst for a 0.3 Hz column on the reddest joint; over 17 bins it was 1.3-2.0 times, so
the smoother is wide by default. Iterating the reference fit as GLS made it worse (its residual is deflated more).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["NoiseModel", "GLSFit", "noise_model", "ols"]

HALF_WIDTH = 32  # Daniell smoother: 2 m + 1 = 65 bins (see the module docstring: 8 bins gave 1.5-2x too small errors)


def _dft(x: np.ndarray, n: int) -> np.ndarray:
    """rfft along time, scaled by 1/sqrt(N) (a white series of variance s^2 gives E|d_k|^2 = s^2)."""
    return np.fft.rfft(np.asarray(x, dtype=float), n=n, axis=0) / math.sqrt(n)


def _real_bins(k: np.ndarray, n: int) -> np.ndarray:
    return (k == 0) | ((n % 2 == 0) & (k == n // 2))


def _smooth(i_k: np.ndarray, m: int, n: int) -> np.ndarray:
    """Daniell average of the cross-periodogram (M, 7, 7) over 2 m + 1 bins; beyond 0 Hz and the Nyquist bin the
    periodogram of a real series continues as the conjugate of its mirror image."""
    if m == 0:
        return i_k.copy()
    nm = i_k.shape[0]
    lo = np.conj(i_k[1:m + 1][::-1])  # bins -m..-1
    top = nm - 2 if n % 2 == 0 else nm - 1  # the last bin that has a mirror beyond the end
    hi = np.conj(i_k[top - m + 1:top + 1][::-1]) if m else i_k[:0]
    ext = np.concatenate([lo, i_k, hi], axis=0)
    c = np.cumsum(np.concatenate([np.zeros((1,) + ext.shape[1:], ext.dtype), ext]), axis=0)
    w = 2 * m + 1
    return (c[w:w + nm] - c[:nm]) / w


@dataclass
class GLSFit:
    """The Whittle / feasible-GLS estimate of a set of columns: ``theta`` (p,), its covariance ``cov`` (p, p) (the
    inverse Fisher information of the Whittle likelihood), the maximum log-likelihood ``loglik`` (comparable between
    column sets under the same :class:`NoiseModel`), and the residual's transform in the band (K, 7)."""

    theta: np.ndarray
    cov: np.ndarray
    loglik: float
    residual_dft: np.ndarray
    n_bins: int

    @property
    def se(self) -> np.ndarray:
        return np.sqrt(np.diag(self.cov))

    def ci95(self) -> np.ndarray:
        """(p, 2) two-sided 95 % intervals (normal)."""
        h = 1.959963984540054 * self.se
        return np.column_stack([self.theta - h, self.theta + h])


@dataclass
class NoiseModel:
    """The residual's 7x7 cross-spectral matrix in the bins of a band, estimated once per log.

    ``fs`` Hz and ``n`` samples of the log; ``bins`` (K,) the rfft indices of the band and ``freqs`` (K,) Hz;
    ``P`` (K, 7, 7) the spectral matrix in per-sample units (Nm^2: the variance of a white series at every bin),
    ``W`` its inverse and ``logdet`` (K,) its log-determinant; ``real`` (K,) marks 0 Hz and Nyquist; ``half_width``
    the Daniell smoother's m."""

    fs: float
    n: int
    bins: np.ndarray
    freqs: np.ndarray
    P: np.ndarray
    W: np.ndarray
    logdet: np.ndarray
    real: np.ndarray
    half_width: int

    @classmethod
    def from_reference(cls, y: np.ndarray, columns: np.ndarray, fs: float, band: tuple[float, float] | None = None,
                       half_width: int = HALF_WIDTH) -> NoiseModel:
        """The noise model of the residual of a generous reference fit: ordinary least squares of ``y`` (N, 7) on
        ``columns`` (N, 7, p) over every sample, then :func:`noise_model` of what remains."""
        theta = ols(columns, y)
        return noise_model(y - np.einsum("njp,p->nj", columns, theta), fs, band, half_width)

    @property
    def csd(self) -> np.ndarray:
        """The one-sided cross-spectral density (K, 7, 7) in Nm^2/Hz: ``E[x_a x_b^*]`` convention, 2 P / fs inside
        the spectrum and P / fs at its real bins (``scipy.signal.csd(x_b, x_a, fs)`` estimates the same)."""
        return np.where(self.real[:, None, None], 1.0, 2.0) * self.P / self.fs

    def dft(self, x: np.ndarray) -> np.ndarray:
        """Transform of ``x`` (N, 7) or (N, 7, p) at the band's bins: (K, 7) or (K, 7, p)."""
        x = np.asarray(x, dtype=float)
        if x.shape[0] != self.n:
            raise ValueError(f"the noise model is of a log of {self.n} samples, got {x.shape[0]}")
        return _dft(x, self.n)[self.bins]

    def loglik(self, residual_dft: np.ndarray) -> float:
        """Whittle log-likelihood of a residual's transform (K, 7) under this model."""
        q = np.real(np.einsum("ka,kab,kb->k", np.conj(residual_dft), self.W, residual_dft))
        c = np.where(self.real, 0.5, 1.0)
        norm = np.where(self.real, self.logdet + 7 * math.log(2 * math.pi), self.logdet + 7 * math.log(math.pi))
        return float(-np.sum(c * (norm + q)))

    def fit(self, columns: np.ndarray | None, y: np.ndarray, ridge: float = 0.0) -> GLSFit:
        """Feasible GLS (the Whittle maximum) of ``y`` (N, 7) on ``columns`` (N, 7, p) (None or p = 0: no
        parameters, the log-likelihood of ``y`` itself). ``ridge`` (>= 0) adds ``ridge * I`` to the information, a
        Gaussian prior of variance 1/ridge on each parameter (0: none)."""
        yk = self.dft(y)
        if columns is None or np.asarray(columns).shape[-1] == 0:
            return self.fit_dft(None, yk)
        if np.ndim(columns) != 3 or np.shape(columns)[1] != 7:
            raise ValueError(f"columns must have shape (N, 7, p), got {np.shape(columns)}")
        return self.fit_dft(self.dft(columns), yk, ridge)

    def fit_dft(self, ak: np.ndarray | None, yk: np.ndarray, ridge: float = 0.0) -> GLSFit:
        """:meth:`fit` from the transforms (:meth:`dft`) of the columns (K, 7, p) and of ``y`` (K, 7): a search over
        many column sets transforms each column once."""
        if ak is None or ak.shape[-1] == 0:
            return GLSFit(np.zeros(0), np.zeros((0, 0)), self.loglik(yk), yk, len(self.bins))
        c = np.where(self.real, 1.0, 2.0)[:, None, None]
        wa = self.W @ ak  # (K, 7, p)
        info = np.sum(c * np.real(np.conj(ak).transpose(0, 2, 1) @ wa), axis=0)
        info = 0.5 * (info + info.T) + ridge * np.eye(info.shape[0])
        b = np.sum(c[:, :, 0] * np.real(np.einsum("kap,ka->kp", np.conj(wa), yk)), axis=0)
        # W is Hermitian: conj(W A)^T y = A^H W y
        cov = np.linalg.pinv(info, hermitian=True)
        theta = cov @ b
        r = yk - ak @ theta
        return GLSFit(theta, cov, self.loglik(r), r, len(self.bins))


def noise_model(residual: np.ndarray, fs: float, band: tuple[float, float] | None = None,
                half_width: int = HALF_WIDTH) -> NoiseModel:
    """The :class:`NoiseModel` of ``residual`` (N, 7) sampled uniformly at ``fs`` Hz: its cross-periodogram smoothed
    over ``2 half_width + 1`` bins, kept in ``band`` = (low, high) Hz (default: 0 to fs/2, both ends included)."""
    e = np.asarray(residual, dtype=float)
    if e.ndim != 2 or e.shape[1] != 7:
        raise ValueError(f"residual must have shape (N, 7), got {e.shape}")
    n = e.shape[0]
    if n < 4 * (2 * half_width + 1):
        raise ValueError(f"{n} samples are too few for a spectrum smoothed over {2 * half_width + 1} bins")
    if not np.isfinite(e).all():
        raise ValueError("the residual holds NaN or inf")
    d = _dft(e, n)
    p = _smooth(d[:, :, None] * np.conj(d[:, None, :]), half_width, n)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    lo, hi = (0.0, fs / 2) if band is None else band
    bins = np.nonzero((f >= lo) & (f <= hi))[0]
    if len(bins) == 0:
        raise ValueError(f"no frequency bin in the band {lo:g}-{hi:g} Hz (bins {fs / n:.3g} Hz apart)")
    p = p[bins]
    real = _real_bins(bins, n)
    p[real] = p[real].real
    p = 0.5 * (p + np.conj(p.transpose(0, 2, 1)))
    scale = np.real(np.trace(p, axis1=1, axis2=2)) / 7
    p = p + (1e-12 * scale)[:, None, None] * np.eye(7)  # full rank where a joint is silent
    sign, logdet = np.linalg.slogdet(p)
    if np.any(np.real(sign) <= 0):
        raise ValueError("the residual's spectral matrix is singular in the band (a joint with no noise at all?)")
    return NoiseModel(float(fs), n, bins, f[bins], p, np.linalg.inv(p), np.real(logdet), real, int(half_width))


def ols(columns: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Ordinary least squares of ``y`` (N, 7) on ``columns`` (N, 7, p) over every sample and joint."""
    a = np.asarray(columns, dtype=float)
    n, j, p = a.shape
    return np.linalg.lstsq(a.reshape(n * j, p), np.asarray(y, dtype=float).reshape(n * j), rcond=None)[0]
