"""The covariance of least-squares parameters fitted to a robot log's residual (the sandwich the intervals of
:mod:`~franka_vs_gym.validation.uncertainty` use).

**Noise model.** The residual of a robot log is not white: the torque is low-pass filtered (neighbouring 1 kHz
samples are nearly equal), what the model still lacks follows the motion for seconds, and the noise differs between
joints and with speed. The ordinary least-squares covariance ``s^2 (X^T X)^-1`` (what ``mujoco.sysid``'s
``calculate_intervals`` reports) assumes independent samples and is then far too narrow. This module uses a
**sandwich** covariance ``B Omega B`` (``B = (J^T J)^-1`` on the identifiable subspace) whose middle ``Omega`` is the
long-run variance of the per-sample scores ``g_t = sum_j J[t, j, :] e[t, j]`` (summing over the joints of one
sample keeps the cross-joint correlation), estimated by the **equal-weighted cosine (EWC)** estimator: the average
of ``nu`` outer products of the scores' projections onto the lowest cosines ``cos(pi k (t + 1/2) / N)``,
``k = 1..nu`` (Lazarus, Lewis, Stock and Watson, "HAR inference: recommendations for practice", J. Bus. Econ. Stat.
36(4), 2018). Why this and not the alternatives:

- it is heteroscedasticity- *and* autocorrelation-consistent (HAC), like Newey-West, but its t-statistic follows a
  Student t with ``nu`` degrees of freedom exactly under fixed-smoothing asymptotics, so the interval uses
  ``t_nu(0.975)`` instead of 1.96 and keeps its coverage on strongly persistent series, where Newey-West with
  normal critical values is known to under-cover (measured here: ``scripts/coverage_study.py``);
- it needs one DCT of the scores, ``O(N log N)`` per parameter, where a moving-block bootstrap needs hundreds of
  refits (the budget is 5 s for a 30 s, 1 kHz diagnosis);
- ``nu`` is set from the log itself: ``nu = 0.4 N_eff^(2/3)`` (the rule of Lazarus et al. with the effective
  number of samples ``N_eff = N / tau_int`` of the parameters' influence series in place of ``N``), at most
  ``N_eff / 4`` (the highest cosine stays below the corner of the scores' spectrum), between 2 and ``MAX_DOF``: a
  log with few independent samples gets few degrees of freedom and an honestly wide Student quantile.

**Low-frequency noise under a slow regressor.** EWC assumes the scores' spectrum is flat over its ``nu`` lowest
cosines. On a slow motion it is not: a regressor whose energy sits in the log's lowest one or two frequency bins
(an acceleration on 0.1 Hz point-to-point moves or slow multi-sines) meets the noise where 1/f noise and a slow
drift are several times the white level, and the band average dilutes that (measured on generator B with
``scripts/coverage_study.py --redraws 40``: no bias in the armature fit, median ratio to the truth 1.01-1.04, but a
spread 1.5-1.6 times what EWC claims and 78-81 % coverage). So ``method="hac"`` also computes the
**spectral** sandwich of :func:`_meat_spectral` (``(1/N) sum_f J(f)^H S_e(f) J(f)``: the residual's smoothed
cross-periodogram weighted by each regressor's own spectrum, with Satterthwaite degrees of freedom per parameter)
and keeps, parameter by parameter, the wider of the two intervals (each with its own Student quantile, folded into
the covariance so that +-1.96 standard deviations is the interval): EWC covers heteroscedastic noise, the spectral
estimate covers noise coloured where the regressor lives (the same redraws: 95-98 % coverage).

``method="hac"`` (the default of :func:`parameter_covariance`) is this combination; ``"ewc"`` and ``"spectral"``
alone, ``"newey_west"`` (Bartlett kernel, Andrews' AR(1) bandwidth, normal quantile) and ``"ols"`` (white noise, as
``mujoco.sysid``) are there for comparison (the coverage study and the test show what they do on robot logs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import fft as sfft
from scipy import stats

NULL_TOL = 1e-9  # relative eigenvalue of the scaled normal matrix below which a direction is not identified
MAX_DOF = 200
LEVEL = 0.95



# ------------------------------------------------------------------------------------------ the covariance itself
def _scores(X: np.ndarray, residual: np.ndarray) -> np.ndarray:
    X = np.asarray(X, dtype=np.float64)
    e = np.asarray(residual, dtype=np.float64)
    if X.ndim == 2:
        if e.shape != (X.shape[0],):
            raise ValueError(f"residual must have shape ({X.shape[0]},), got {e.shape}")
        return X * e[:, None]
    if X.ndim != 3 or e.shape != X.shape[:2]:
        raise ValueError(f"X (N, k, P) and residual (N, k) do not match: {X.shape} vs {e.shape}")
    return np.matmul(X.transpose(0, 2, 1), e[:, :, None])[:, :, 0]


def ewc_dof(influence: np.ndarray) -> int:
    """Degrees of freedom ``nu`` of the EWC estimator for influence series (N, P): ``0.4 N_eff^(2/3)`` with the
    smallest effective sample size among the columns, at most ``N_eff / 4`` (the highest cosine then stays below
    the corner frequency of the series' spectrum), clipped to [2, MAX_DOF]."""
    n = influence.shape[0]
    var = influence.var(axis=0)
    cols = [c for c in range(influence.shape[1]) if var[c] > 0]
    if not cols:
        return MAX_DOF
    from franka_vs_gym.validation.selection import n_eff

    neff = max(float(np.min(n_eff(influence[:, cols], max_lag=min(4000, n - 1)))), 1.0)  # one batched FFT
    nu = min(0.4 * neff ** (2.0 / 3.0), 0.25 * neff)
    return int(np.clip(round(nu), 2, MAX_DOF))


def _meat_ewc(g: np.ndarray, nu: int) -> np.ndarray:
    n = g.shape[0]
    c = sfft.dct(g, type=2, axis=0)[1:nu + 1] * math.sqrt(2.0 / n) / 2.0  # (nu, P): sqrt(2/N) sum g cos(...)
    return n * (c.T @ c) / nu  # long-run variance of the sum of the scores


def _andrews_bandwidth(g: np.ndarray) -> int:
    """Andrews (1991) AR(1) plug-in bandwidth of the Bartlett kernel."""
    n = g.shape[0]
    num = den = 0.0
    for c in range(g.shape[1]):
        x = g[:, c] - g[:, c].mean()
        d = float(x[:-1] @ x[:-1])
        if d <= 0:
            continue
        rho = float(np.clip(x[1:] @ x[:-1] / d, -0.999, 0.999))
        s2 = float(np.mean((x[1:] - rho * x[:-1]) ** 2))
        num += 4 * rho ** 2 * s2 ** 2 / ((1 - rho) ** 6 * (1 + rho) ** 2)
        den += s2 ** 2 / (1 - rho) ** 4
    alpha = num / den if den > 0 else 0.0
    return int(min(max(1, math.ceil(1.1447 * (alpha * n) ** (1.0 / 3.0))), n // 2))


def _meat_newey_west(g: np.ndarray, lag: int) -> np.ndarray:
    """Bartlett-weighted sum of autocovariances, exactly, as the sum of outer products of window sums."""
    n, p = g.shape
    pad = np.vstack([np.zeros((lag + 1, p)), g, np.zeros((lag, p))])
    cs = np.cumsum(pad, axis=0)
    S = cs[lag + 1:] - cs[:-(lag + 1)]  # sums of g over windows of lag + 1 samples (partial at the edges)
    return (S.T @ S) / (lag + 1)


SMOOTH_REL = 0.15  # half-width of the residual periodogram's smoothing window, relative to the frequency
TAIL = 1e-4  # share of a regressor's energy at the highest frequencies the spectral estimate leaves out


def _meat_spectral(J: np.ndarray, e: np.ndarray, B: np.ndarray, rel: float = SMOOTH_REL,
                   nonzero: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Frequency-domain middle of the sandwich and each parameter's degrees of freedom.

    For a regressor ``J`` (N, k, P) fixed by the motion and a stationary error ``e`` (N, k), the variance of the
    score sum is exactly ``(1/N) sum_f J(f)^H S_e(f) J(f)`` over the DFT frequencies (Parseval): the error's
    spectrum weighted by the regressor's. ``S_e`` is the residual's cross-periodogram (k x k) smoothed over
    ``+-rel * f`` (at least the neighbouring bins): a constant relative bandwidth, so a steep low-frequency
    spectrum (1/f noise, a slow drift, an AR(1) with a long correlation time) is followed where it is steep. The
    degrees of freedom of parameter p are Satterthwaite's for this weighted sum of periodogram ordinates (each
    chi^2 with 2): a parameter whose regressor lives in two frequency bins of the log gets about 4, whatever N.
    ``nonzero`` (k, P): which joints' columns of each parameter are not zero, when the caller knows."""
    n, k, p = J.shape
    if nonzero is None:
        nonzero = np.abs(J).max(axis=0) > 0
    jj, pp = np.nonzero(nonzero)  # the (joint, parameter) columns that are not zero
    Cf = sfft.rfft(J[:, jj, pp], axis=0)  # (K, C): per-joint effects have one column per parameter, not k
    E = sfft.rfft(e, axis=0)  # (K, k)
    K = E.shape[0]
    w = np.full(K, 2.0)  # rfft: each bin but 0 (and N/2) stands for itself and its mirror
    w[0] = 1.0
    if n % 2 == 0:
        w[-1] = 1.0
    H = np.zeros((len(jj), p))
    H[np.arange(len(jj)), pp] = 1.0
    # the regressors are functions of the low-passed motion: the bins above the last one where any parameter
    # still has TAIL of its energy are left out (its variance changes by about TAIL times the ratio of the noise
    # spectrum there to the spectrum where the regressor lives; their periodogram still enters the windows below)
    pw = ((Cf.real ** 2 + Cf.imag ** 2) * w[:, None]) @ H  # (K, P)
    tail = np.cumsum(pw[::-1], axis=0)[::-1] / np.maximum(pw.sum(axis=0), 1e-300)
    Kc = int(min(K, max(3, np.nonzero((tail > TAIL).any(axis=1))[0].max(initial=1) + 2)))
    G = int(min(K, Kc + max(1, math.floor(rel * Kc)) + 1))  # the periodogram ordinates the windows reach
    I = E[:G, :, None] * E[:G, None, :].conj() / n  # (G, k, k) cross-periodogram
    cs = np.concatenate([np.zeros((1, k, k), complex), np.cumsum(I, axis=0)])
    f = np.arange(Kc)
    h = np.maximum(1, np.floor(rel * f)).astype(int)
    lo = np.clip(f - h, 1, G - 1)  # the mean (bin 0) is never used: it is what an offset would fit
    hi = np.clip(f + h, 1, G - 1)
    m = hi - lo + 1
    S = (cs[hi + 1] - cs[lo]) / m[:, None, None]  # (Kc, k, k)
    cols = [np.nonzero(jj == j)[0] for j in range(k)]
    Jc = np.zeros((Kc, k, p), complex)  # the influence functions in frequency, joint by joint
    lev = np.zeros((G, k))  # the fit's leverage at each ordinate: the share of its noise power the fit removed
    for i in range(k):
        if len(cols[i]):
            Jc[:, i, :] = Cf[:Kc, cols[i]] @ B[pp[cols[i]], :]
            lev[:Kc, i] = np.einsum("fa,fa->f", Jc[:, i, pp[cols[i]]], Cf[:Kc, cols[i]].conj()).real / n
    # the residual's periodogram is short of the fitted part (E I_e = S (1 - leverage), the frequency-domain
    # counterpart of HC2's 1 / (1 - h_tt)): a parameter living in two bins takes a real share of their power
    cl = np.concatenate([np.zeros((1, k)), np.cumsum(lev, axis=0)])
    keep = 1.0 - np.clip((cl[hi + 1] - cl[lo]) / m[:, None], 0.0, 0.9)  # (Kc, k)
    S = S / np.sqrt(keep[:, :, None] * keep[:, None, :])
    Cc = Cf[:Kc] * np.sqrt(w[:Kc])[:, None]
    M = np.zeros((len(jj), len(jj)))  # sum_f Re(conj(C_a) S[j_a, j_b] C_b), joint pair by joint pair
    for i in range(k):
        if not len(cols[i]):
            continue
        Xi = Cc[:, cols[i]].conj().T
        for j in range(k):
            if len(cols[j]):
                M[np.ix_(cols[i], cols[j])] = (Xi @ (S[:, i, j, None] * Cc[:, cols[j]])).real
    meat = H.T @ M @ H / n
    wc = w[:Kc]
    # degrees of freedom: var_p = sum_f' c_f' I_f' (diagonal), c_f' = sum over the windows containing f'
    Jb = Jc
    a = (wc[:, None, None] * (Jb.real ** 2 + Jb.imag ** 2) / n) / m[:, None, None]  # (Kc, k, P)
    A = np.concatenate([np.zeros((1, k, p)), np.cumsum(a, axis=0)])
    g = np.arange(int(hi[-1]) + 1)  # the ordinates the windows use
    first = np.searchsorted(hi, g, side="left")  # windows containing g: first..last (lo, hi non-decreasing)
    last = np.minimum(np.searchsorted(lo, g, side="right") - 1, Kc - 1)
    c = A[np.maximum(last + 1, first)] - A[np.minimum(first, Kc)]
    Sd = _smoothed_diag(cs, g, rel, G)  # the ordinates' means: the smoothed spectrum at each
    v = c * Sd[:, :, None]  # (G, k, P): each ordinate's share of var_p (the smoothed spectrum as its mean)
    num = v.sum(axis=(0, 1)) ** 2
    den = (v ** 2).sum(axis=(0, 1))
    dof = np.where(den > 0, 2.0 * num / np.maximum(den, 1e-300), np.inf)
    return meat, dof


def _smoothed_diag(cs: np.ndarray, g: np.ndarray, rel: float, K: int) -> np.ndarray:
    """Diagonal of the smoothed periodogram at bins ``g`` (``cs``: cumulative periodogram with a leading zero)."""
    h = np.maximum(1, np.floor(rel * g)).astype(int)
    lo = np.clip(g - h, 1, K - 1)
    hi = np.clip(g + h, 1, K - 1)
    return np.einsum("fjj->fj", (cs[hi + 1] - cs[lo]) / (hi - lo + 1)[:, None, None]).real


def _fold_dof(cov: np.ndarray, dof: np.ndarray) -> np.ndarray:
    """``cov`` with each parameter's Student quantile folded in: scaled so that +-z_0.975 sd is its t interval."""
    z = stats.norm.ppf((1 + LEVEL) / 2)
    r = np.where(np.isfinite(dof), stats.t.ppf((1 + LEVEL) / 2, np.clip(dof, 1.0, None)) / z, 1.0)
    return cov * np.outer(r, r)


@dataclass
class Covariance:
    """A parameter covariance with what its intervals need: ``cov`` (P, P), the Student degrees of freedom ``dof``
    (``inf``: normal quantile), the unidentified directions ``null`` (P, m) in raw parameter units, the column
    scales and the method."""

    cov: np.ndarray
    dof: float
    null: np.ndarray
    scale: np.ndarray
    method: str
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def quantile(self) -> float:
        q = (1 + LEVEL) / 2
        return float(stats.norm.ppf(q) if not np.isfinite(self.dof) else stats.t.ppf(q, self.dof))

    def se(self) -> np.ndarray:
        return np.sqrt(np.maximum(np.diag(self.cov), 0.0))

    def identified(self) -> np.ndarray:
        """(P,) True where the parameter does not move along an unidentified direction."""
        if self.null.shape[1] == 0:
            return np.ones(len(self.scale), bool)
        v = self.null * self.scale[:, None]  # scaled coordinates, unit columns
        return np.max(np.abs(v), axis=1) < 1e-3


def covariance(X: np.ndarray, residual: np.ndarray, *, method: str = "hac", gram: np.ndarray | None = None,
               dof: int | None = None, bandwidth: int | None = None, nonzero: np.ndarray | None = None
               ) -> Covariance:
    """The covariance of least-squares parameters fitted to ``residual`` with regressor ``X`` ((N, P) or (N, k, P)
    with ``residual`` (N, k): k channels sampled together, e.g. the 7 joints), see the module docstring.
    ``gram``: ``X^T X`` when already known; ``nonzero`` (k, P): the channels each column of X is not zero on."""
    X = np.asarray(X, dtype=np.float64)
    g = _scores(X, residual)
    n, p = g.shape
    if n < 8:
        raise ValueError(f"{n} samples are too few for a covariance")
    if gram is None:
        Xf = X.reshape(-1, p)
        gram = Xf.T @ Xf
    scale = np.sqrt(np.maximum(np.diag(gram), 1e-300))
    Gs = gram / np.outer(scale, scale)
    w, V = np.linalg.eigh(0.5 * (Gs + Gs.T))
    top = max(float(w[-1]), 1e-300)
    ok = w > NULL_TOL * top
    Binv_s = (V[:, ok] / w[ok]) @ V[:, ok].T  # pseudo-inverse in scaled coordinates
    B = Binv_s / np.outer(scale, scale)
    null = V[:, ~ok] / scale[:, None]
    info: dict[str, Any] = {}
    if method == "hac":  # the larger of the two, parameter by parameter, each with its own Student quantile
        e = np.asarray(residual, dtype=np.float64)
        Xk, ek = (X, e) if X.ndim == 3 else (X[:, None, :], e[:, None])
        nu = int(dof) if dof is not None else ewc_dof(g @ B)
        c_ewc = B @ _meat_ewc(g, nu) @ B
        meat_f, dof_f = _meat_spectral(Xk, ek, B, nonzero=nonzero if X.ndim == 3 else None)
        c_spec = B @ meat_f @ B
        v_e = np.diag(_fold_dof(c_ewc, np.full(p, float(nu))))
        v_f = np.diag(_fold_dof(c_spec, np.maximum(dof_f, 2.0)))
        sd = np.sqrt(np.maximum(np.maximum(v_e, v_f), 0.0))
        d_f = np.sqrt(np.maximum(np.diag(c_spec), 0.0))
        corr = c_spec / np.outer(np.where(d_f > 0, d_f, 1.0), np.where(d_f > 0, d_f, 1.0))
        cov = corr * np.outer(sd, sd)
        info.update(nu=nu, dof_spectral=dof_f, spectral_wins=v_f > v_e)
        return Covariance(0.5 * (cov + cov.T), math.inf, null, scale, method, info)
    if method in ("ewc", "spectral"):
        if method == "ewc":
            infl = g @ B
            nu = int(dof) if dof is not None else ewc_dof(infl)
            meat = _meat_ewc(g, nu)
            dof_t: float = float(nu)
            info["nu"] = nu
        else:
            e = np.asarray(residual, dtype=np.float64)
            Xk, ek = (X, e) if X.ndim == 3 else (X[:, None, :], e[:, None])
            meat, dof_f = _meat_spectral(Xk, ek, B, nonzero=nonzero if X.ndim == 3 else None)
            cov = _fold_dof(B @ meat @ B, np.maximum(dof_f, 2.0))
            info["dof_spectral"] = dof_f
            return Covariance(0.5 * (cov + cov.T), math.inf, null, scale, method, info)
    elif method == "newey_west":
        lag = int(bandwidth) if bandwidth is not None else _andrews_bandwidth(g @ B)
        meat = _meat_newey_west(g, lag)
        dof_t = math.inf
        info["bandwidth"] = lag
    elif method == "ols":
        e = np.asarray(residual, dtype=np.float64).ravel()
        s2 = float(e @ e) / max(e.size - p, 1)
        cov = s2 * B
        return Covariance(0.5 * (cov + cov.T), float(max(e.size - p, 1)), null, scale, method, info)
    else:
        raise ValueError(f"unknown covariance method {method!r}: use 'hac', 'ewc', 'spectral', 'newey_west' or "
                         "'ols'")
    cov = B @ meat @ B
    return Covariance(0.5 * (cov + cov.T), dof_t, null, scale, method, info)


def parameter_covariance(X: np.ndarray, residual: np.ndarray, *, method: str = "hac", **kw: Any) -> np.ndarray:
    """(P, P) covariance of the least-squares parameters of ``residual`` on ``X`` ((N, P), or (N, k, P) with
    ``residual`` (N, k)); ``method``: ``"hac"`` (equal-weighted cosine HAC, the workbench's), ``"newey_west"`` or
    ``"ols"``. Directions the regressor does not identify get zero variance here (see :func:`covariance` for them
    and for the Student degrees of freedom)."""
    return covariance(X, residual, method=method, **kw).cov


__all__ = ["Covariance", "covariance", "ewc_dof", "parameter_covariance"]
