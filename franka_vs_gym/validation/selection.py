"""Joint least-squares fits of sets of effects, cross-validated from cached Gram matrices, and the in-context
selection that ``diagnose`` runs.

Every effect is linear in its coefficients once its shape is fixed (see :mod:`franka_vs_gym.validation.effects`), so
a set of effects is fitted *jointly* by one linear least-squares problem. The log is cut into ``F`` contiguous blocks;
for each block ``f`` and joint ``j`` the engine keeps the Gram blocks ``X_fj^T X_fj``, ``X_fj^T y_fj`` and
``y_fj^T y_fj`` of every effect pair it has seen, so fitting any set on all blocks but one and scoring it on the
held-out block costs a few small solves, not a pass over the data. That is what makes selection *in context*
affordable: each candidate is re-fitted together with the effects already selected, earlier selections are re-tested
once later ones are in, and collinear pairs are tried as groups.

Scores (the same information criterion as the ranking; see :mod:`franka_vs_gym.validation.diagnose`): adding a set of
coefficients to a model whose held-out mean squared error per joint is ``MSE0_j`` and becomes ``MSE1_j`` scores
``sum_j N_eff_j ln(MSE0_j / MSE1_j) - k ln(N_eff)``, with ``N_eff`` the effective sample size of the current residual
under its autocorrelation.

**The motion band** (``Engine(..., band=True)``; ``diagnose``'s default, ``evidence="band"``). Every
effect is a function of the motion, which cleaning low-passes at its cutoff (10 Hz), so effects live below the
cutoff; the torque measured above it (most of a real log's noise once its model is close) is the same for every
candidate and carries no information about them. The scores are therefore taken in the motion band: ``MSE`` less the
target's power above the cutoff (:attr:`Engine.hf`, :meth:`Engine.band`), and ``N_eff`` of the residual low-passed
at the cutoff (:meth:`Engine.lowpass`). Without this, a 1 kHz log whose residual is mostly broadband noise counted
each of its samples as independent evidence (N_eff about 2000-2500 per 20 s on the Gaz et al. 2019 log after
selection, against 40-250 at 30 Hz and 330-380 for the low-passed residual at either rate), and laws removing a
tenth of the noise floor from the real robot's own unmodelled structure became significant. In the band the same log
gives the same answer at 1 kHz, 100 Hz and 30 Hz; but the low-passed residual of a real log is mostly slow model
error, whose N_eff (about 20-30 per 20 s) no longer affords a 43-parameter change of the link inertials that held-
out data confirm on that log: ``diagnose`` therefore confirms such a term by the blocked held-out test.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import fft as sp_fft
from scipy import signal

from franka_vs_gym.validation.effects import Context, Effect, Fit
from franka_vs_gym.validation.signals import band_sos


def contiguous_folds(n: int, k: int) -> list[np.ndarray]:
    """``k`` contiguous blocks of ``range(n)``, the held-out folds of the selection."""
    edges = np.linspace(0, n, k + 1).astype(int)
    return [np.arange(edges[i], edges[i + 1]) for i in range(k)]


def n_eff(r: np.ndarray, max_lag: int = 2000) -> np.ndarray | float:
    """Effective number of independent samples of a series r (N,) or of each column of r (N, k):
    N / tau_int with tau_int = 1 + 2 * (sum of the autocorrelations up to the first non-positive one)."""
    x = np.asarray(r, dtype=np.float64)
    one = x.ndim == 1
    if one:
        x = x[:, None]
    n = x.shape[0]
    x = x - x.mean(axis=0)
    var = np.einsum("nk,nk->k", x, x)
    lag = min(max_lag, n - 1)
    m = sp_fft.next_fast_len(n + lag + 1, real=True)  # any length >= n + lag keeps lags <= lag free of wrap-around
    f = sp_fft.rfft(x, m, axis=0)
    ac = sp_fft.irfft(f.real ** 2 + f.imag ** 2, m, axis=0)[: lag + 1] / np.maximum(var, 1e-300)
    out = np.empty(x.shape[1])
    for c in range(x.shape[1]):
        if var[c] <= 0:
            out[c] = n
            continue
        neg = np.nonzero(ac[1:, c] <= 0)[0]
        k = int(neg[0]) if len(neg) else lag
        tau = 1.0 + 2.0 * float(ac[1:k + 1, c].sum())
        out[c] = n / max(tau, 1.0)
    return float(out[0]) if one else out


@dataclass(eq=False)
class Term:
    """One effect in a set: its shape (non-linear parameters), and for a per-joint effect the joints it acts on."""

    effect: Effect
    shape: dict[str, Any]
    joints: list[int] | None = None  # per-joint effects only

    @property
    def key(self) -> tuple:
        k = self.__dict__.get("_key")
        if k is None:  # computed once: a term's effect and shape do not change after construction
            k = self.__dict__["_key"] = (self.effect.name, self.effect.shape_key(self.shape))
        return k

    def active(self, j: int) -> bool:
        return not self.effect.per_joint or (self.joints is not None and j in self.joints)

    def k(self) -> int:
        """Number of parameters (for the information criterion)."""
        e = self.effect
        return e.n_params * (len(self.joints or []) if e.per_joint else 1)


@dataclass
class SetFit:
    """A set of terms fitted jointly: held-out MSE per joint (7,), in-sample coefficients per term, in-sample
    contribution (N, 7) and the fits."""

    terms: list[Term]
    mse_cv: np.ndarray
    coefs: list[np.ndarray]
    fits: list[Fit] = field(default_factory=list)
    _contribs: list[np.ndarray] | None = None
    _band_neff: np.ndarray | None = None
    #: (F, 7) held-out sum of squared errors of each block (Nm^2), when cross-validated
    sse_folds: np.ndarray | None = None


class Engine:
    """Cached cross-validated joint fits of sets of effects on one target ``y`` (N, 7) Nm."""

    def __init__(self, ctx: Context, y: np.ndarray, folds: list[np.ndarray], band: bool = False) -> None:
        self.ctx, self.y, self.folds = ctx, y, folds
        self.F = len(folds)
        self.n = len(y)
        # contiguous blocks are taken as slices: views instead of copies of each design (same numbers)
        self._blocks = [slice(int(b[0]), int(b[-1]) + 1) if len(b) and np.array_equal(b, np.arange(b[0], b[-1] + 1))
                        else b for b in folds]
        self.yy = np.array([np.einsum("nj,nj->j", y[b], y[b]) for b in self._blocks])  # (F, 7)
        self._design: dict[tuple, np.ndarray] = {}
        self._xy: dict[tuple, np.ndarray] = {}
        self._gram: dict[tuple, np.ndarray] = {}
        self.empty_mse = self.yy.sum(axis=0) / self.n
        self._sos = band_sos(ctx.data.settings, self.n) if band else None
        #: (7,) the target's power above the motion band (Nm^2): no effect removes it, so scores leave it out
        self.hf = np.mean((y - self.lowpass(y)) ** 2, axis=0) if self._sos is not None else np.zeros(y.shape[1])

    def lowpass(self, r: np.ndarray) -> np.ndarray:
        """``r`` (N, 7) low-passed (zero phase) at the cleaning cutoff: its part in the motion band (``r`` itself
        when the engine scores on the whole band)."""
        if self._sos is None:
            return r
        return signal.sosfiltfilt(self._sos, r, axis=0)

    def band(self, mse: np.ndarray) -> np.ndarray:
        """Mean squared errors (7,) in the motion band: ``mse`` less the target's power above the cutoff (kept
        above a thousandth of that power: a held-out error never falls below what no effect can remove)."""
        return np.maximum(np.asarray(mse, dtype=np.float64) - self.hf, 1e-3 * self.hf + 1e-30)

    def band_neff(self, sf: SetFit) -> np.ndarray:
        """Effective sample size (7,) of the fitted set's residual in the motion band (at least 2); kept with the
        set."""
        if sf._band_neff is None:
            sf._band_neff = np.maximum(np.asarray(n_eff(self.lowpass(self.residual(sf)))), 2.0)
        return sf._band_neff.copy()

    # --- caches
    def design(self, t: Term) -> np.ndarray:
        k = t.key
        if k not in self._design:
            D = np.asarray(t.effect.design(self.ctx, t.shape), dtype=np.float64)
            if D.ndim != 3 or D.shape[:2] != (self.n, 7):
                raise ValueError(f"effect {t.effect.name!r}: design must have shape ({self.n}, 7, p), got {D.shape}")
            if not np.isfinite(D).all():
                raise ValueError(f"effect {t.effect.name!r}: design contains NaN or inf")
            self._design[k] = D
        return self._design[k]

    def xy(self, t: Term) -> np.ndarray:  # (F, 7, p)
        k = t.key
        if k not in self._xy:
            D = self.design(t)
            self._xy[k] = np.array([np.einsum("njp,nj->jp", D[b], self.y[b]) for b in self._blocks])
        return self._xy[k]

    def gram(self, a: Term, b: Term) -> np.ndarray:  # (F, 7, pa, pb)
        k = (a.key, b.key)
        if k not in self._gram:
            kt = (b.key, a.key)
            if kt in self._gram:
                return self._gram[kt].transpose(0, 1, 3, 2)
            Da, Db = self.design(a), self.design(b)
            self._gram[k] = np.array([np.matmul(Da[blk].transpose(1, 2, 0), Db[blk].transpose(1, 0, 2))
                                      for blk in self._blocks])
        return self._gram[k]

    # --- fits
    def _layout(self, terms: list[Term]) -> tuple[int, list[dict[int, slice]]]:
        """Global parameter index of each term: {joint: slice} for per-joint terms, {-1: slice} for shared ones."""
        pos = 0
        out = []
        for t in terms:
            p = self.design(t).shape[2]
            d: dict[int, slice] = {}
            if t.effect.per_joint:
                for j in (t.joints or []):
                    d[j] = slice(pos, pos + p)
                    pos += p
            else:
                d[-1] = slice(pos, pos + p)
                pos += p
            out.append(d)
        return pos, out

    def fit(self, terms: list[Term], cv: bool = True) -> SetFit:
        """Fit ``terms`` jointly: held-out MSE per joint (when ``cv``) and in-sample coefficients."""
        P, lay = self._layout(terms)
        if P == 0:
            return SetFit(terms, self.empty_mse.copy(), [np.zeros((7, self.design(t).shape[2])) if
                                                         t.effect.per_joint else np.zeros(self.design(t).shape[2])
                                                         for t in terms], sse_folds=self.yy.copy())
        A = np.zeros((self.F, P, P))
        b = np.zeros((self.F, P))
        per_joint_idx = []
        blocks = []
        grams: dict[tuple[int, int], np.ndarray] = {}  # each pair's (F, 7, pa, pb) looked up once per fit
        xys = [self.xy(t) for t in terms]
        for j in range(7):
            act = [(i, lay[i][j if t.effect.per_joint else -1]) for i, t in enumerate(terms) if t.active(j)]
            if not act:
                per_joint_idx.append(None)
                blocks.append(None)
                continue
            for a, _ in act:
                for c, _ in act:
                    if (a, c) not in grams:
                        grams[a, c] = self.gram(terms[a], terms[c])
            idx = np.concatenate([np.arange(s.start, s.stop) for _, s in act])
            G = np.concatenate([np.concatenate([grams[a, c][:, j] for c, _ in act], axis=2)
                                for a, _ in act], axis=1)  # (F, pj, pj)
            xy = np.concatenate([xys[a][:, j] for a, _ in act], axis=1)  # (F, pj)
            A[:, idx[:, None], idx[None, :]] += G
            b[:, idx] += xy
            per_joint_idx.append(idx)
            blocks.append((G, xy))
        At, bt = A.sum(axis=0), b.sum(axis=0)
        # effects with a prior (``Effect.ridge``, relative to the diagonal of their normal equations) are shrunk
        # toward no change in the directions the log barely excites
        rid = np.zeros(P)
        for t, d in zip(terms, lay, strict=True):
            if getattr(t.effect, "ridge", 0.0):
                for sl in d.values():
                    rid[sl] = t.effect.ridge
        theta = _solve(At + np.diag(rid * np.diag(At)), bt)
        mse_cv = self.empty_mse.copy()
        sse = None
        if cv:
            sse = self.yy.copy()
            Af = At[None] - A  # (F, P, P): each fold's normal equations without its block
            dg = np.diagonal(Af, axis1=1, axis2=2)
            Af = Af + rid[None, :, None] * np.eye(P)[None] * dg[:, None, :]
            ths = _solve_folds(Af, bt[None] - b, np.diag(At))
            for j in range(7):
                if per_joint_idx[j] is None:
                    continue
                G, xy = blocks[j]
                tj = ths[:, per_joint_idx[j]]  # (F, pj)
                sse[:, j] = (self.yy[:, j] - 2 * np.einsum("fp,fp->f", tj, xy)
                             + np.einsum("fp,fp->f", np.einsum("fpq,fq->fp", G, tj), tj))
            mse_cv = np.maximum(sse.sum(axis=0), 0.0) / self.n
        coefs = []
        for t, d in zip(terms, lay, strict=True):
            p = self.design(t).shape[2]
            if t.effect.per_joint:
                c = np.zeros((7, p))
                for j, s in d.items():
                    c[j] = theta[s]
            else:
                c = theta[d[-1]].copy()
            coefs.append(c)
        fits = [t.effect.make_fit(self.ctx, c, t.shape, t.joints if t.effect.per_joint else None)
                for t, c in zip(terms, coefs, strict=True)]
        return SetFit(terms, mse_cv, coefs, fits, sse_folds=sse)

    def contributions(self, sf: SetFit) -> list[np.ndarray]:
        """In-sample contribution (N, 7) Nm of each term of a fitted set."""
        if sf._contribs is None:
            out = []
            for t, c in zip(sf.terms, sf.coefs, strict=True):
                D = self.design(t)
                out.append(np.einsum("njp,jp->nj", D, c) if t.effect.per_joint else D @ c)
            sf._contribs = out
        return sf._contribs

    def residual(self, sf: SetFit) -> np.ndarray:
        return self.y - sum(self.contributions(sf), np.zeros_like(self.y))


def _solve(A: np.ndarray, b: np.ndarray, ref: np.ndarray | None = None) -> np.ndarray:
    """Least-squares coefficients from the normal equations ``A theta = b`` (columns scaled to unit diagonal, a
    1e-9 ridge). A parameter the data do not excite, a zero diagonal or (fitting on all blocks but one) less than
    ``EXCITED`` of its diagonal ``ref`` on the whole log (a column that lives in the held-out block), is not
    estimated: its coefficient is 0. Scaling such a column by its rounding-level diagonal is what blew held-out
    coefficients up to overflow on noise-free logs."""
    d = np.diag(A)
    live = d > (EXCITED * ref if ref is not None else 0.0)
    theta = np.zeros(len(b))
    if not live.any():
        return theta
    if not live.all():
        A, b = A[np.ix_(live, live)], b[live]
        d = d[live]
    try:
        theta[live] = _scaled_solve(A, b, d)
    except np.linalg.LinAlgError:
        scale = np.sqrt(d)
        theta[live] = np.linalg.lstsq(A / np.outer(scale, scale), b / scale, rcond=1e-10)[0] / scale
    return theta


def _scaled_solve(A: np.ndarray, b: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``A theta = b`` (..., P, P), (..., P) with the columns scaled to unit diagonal ``d`` (..., P) and a 1e-9
    ridge: one LAPACK call for a stack of systems. Raises LinAlgError where a system is singular."""
    scale = np.sqrt(d)
    An = A / (scale[..., :, None] * scale[..., None, :])
    return np.linalg.solve(An + 1e-9 * np.eye(A.shape[-1]), (b / scale)[..., None])[..., 0] / scale


def _solve_folds(A: np.ndarray, b: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """:func:`_solve` of every fold's normal equations ``A`` (F, P, P), ``b`` (F, P) at once when every parameter
    is excited in every fold and no system is singular; otherwise fold by fold."""
    d = np.diagonal(A, axis1=1, axis2=2)
    if (d > EXCITED * ref[None, :]).all():
        try:
            return _scaled_solve(A, b, d)
        except np.linalg.LinAlgError:
            pass
    return np.array([_solve(A[f], b[f], ref=ref) for f in range(len(A))])


EXCITED = 1e-9  # share of a parameter's excitation on the whole log below which a fold does not estimate it


__all__ = ["Engine", "SetFit", "Term", "contiguous_folds", "n_eff"]
