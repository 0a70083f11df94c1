"""One criterion for comparing sets of effects: the marginal likelihood (evidence) under one noise model per log.

**The noise model.** Once per log, a generous reference fit (every candidate effect on every joint at once, ordinary
least squares) leaves a residual whose 7x7 cross-spectrum in the motion band (0 Hz to the cleaning cutoff) is the
noise model (:class:`~franka_vs_gym.validation.estimation.NoiseModel`): coloured, correlated across joints, and held
fixed for every comparison. Every effect is linear in its coefficients once its shape is fixed, so under the
band-limited Whittle likelihood a set ``S`` of columns ``A`` (transforms ``A_k`` in the band's bins) is a linear
Gaussian model. Whitening each bin by the Cholesky factor of ``P_k^-1`` and stacking real and imaginary parts gives
``l(theta) = c - 1/2 |y - X theta|^2`` with ``G = X^T X`` the Fisher information.

**The criterion.** Each coefficient has a Gaussian prior ``theta ~ N(0, S)`` centred on no change, its standard
deviation half the largest change the effect's physical range allows (:func:`prior_cov`: payload mass and centre of
mass, friction magnitudes as a share of the joint's torque limit, a tilt on the sphere |g| = 9.81 m/s^2 with the
magnitude within Earth's 0.3 %, a delay in its box, link masses within a factor 2). The evidence of the set is exact:

    ln Z(S) = c + 1/2 b^T (G + S^-1)^-1 b - 1/2 ln det(I + S^1/2 G S^1/2),      b = X^T y

so sets of different size are compared on one scale (the Occam factor is the second term). A set is preferred when its
evidence is larger by more than ``ln B`` (:data:`LOG_RATIO`, the one threshold of the decision: Jeffreys' "strong"
evidence ratio B = 20). The search is greedy over *units* (a per-joint law on one joint, or a shared effect):
forward, the unit that raises ``ln Z`` most while the gain exceeds ``ln B``; backward, after each step, every unit
whose removal costs less than ``ln B`` leaves (weakest first). A set within ``ln B`` of the selected one that swaps one
unit for another effect is reported ``ambiguous`` with it (the output keeps its form:
:class:`~franka_vs_gym.validation.results.Ambiguity`).

The coefficients reported are the engine's least-squares fit of the selected set (as before), so intervals,
contributions and the report do not change their meaning.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from franka_vs_gym.validation.effects import Context, Effect
from franka_vs_gym.validation.effects.base import MAX_DELAY, MAX_PAYLOAD, MAX_TILT, _tau_max
from franka_vs_gym.validation.estimation import HALF_WIDTH, NoiseModel, noise_model
from franka_vs_gym.validation.results import Ambiguity, Candidate, Selected
from franka_vs_gym.validation.selection import Engine, SetFit, Term

__all__ = ["LOG_RATIO", "Library", "EvidenceSelector", "prior_cov"]

#: ln of the evidence ratio B = 20 (Jeffreys' / Kass and Raftery's "strong"): a unit enters when it raises the
#: evidence by more than this, stays while removing it costs more, and two sets within it are not told apart
LOG_RATIO = math.log(20.0)
#: Earth's gravity lies within 9.780-9.832 m/s^2 (normal gravity, GRS 1980): the model's 9.81 is off by <= 0.03
G_MAGNITUDE_RANGE = 0.03
#: the largest centre-of-mass distance of a flange body from the flange the payload law accepts (m)
PAYLOAD_REACH = 0.3
#: link inertials: each link's mass within 30 % of the model's (Gaz et al. 2019 re-identify the FER's links within
#: about that), its first moments and inertia within 30 % of the mass times LINK_REACH and LINK_REACH^2
LINK_SHARE = 0.3
#: a link's length scale (m): the FER's links are 0.1-0.4 m long
LINK_REACH = 0.3
#: divide the log-likelihood by the temperature the blocks show (_temperature)
TEMPERED = True
SEPARATE = ("motions that excite the two differently (this log's data do not tell them apart at the evidence "
            "ratio of the criterion)")


def _half(x):
    """The prior's standard deviation from the largest change a physical range allows: +-2 sd spans it."""
    return 0.5 * np.asarray(x, dtype=float)


def prior_cov(e: Effect, ctx: Context, p: int, joint: int | None) -> np.ndarray | None:
    """(p, p) prior covariance of an effect's coefficients (on ``joint`` for a per-joint law), from its physical
    range; None: a flat prior (an effect the library does not know, held fixed in every compared set)."""
    name = getattr(getattr(e, "base", e), "name", e.name)
    tau = _tau_max(ctx)[joint] if joint is not None else None
    if name in ("viscous_friction", "torque_offset"):  # plausible: |total| < 0.2 tau_max
        sd = _half(0.2 * tau) * np.ones(p)
    elif name in ("coulomb_friction", "sigmoid_friction", "asymmetric_friction", "stribeck_friction"):
        sd = _half(0.25 * tau) * np.ones(p)  # step levels < 0.25 tau_max
    elif name == "load_dependent_friction":
        sd = _half(0.3) * np.ones(p)  # gear efficiency > 70 %
    elif name == "armature":
        sd = _half(2.0) * np.ones(p)  # < 2 kg m^2
    elif name == "delay":
        sd = _half(MAX_DELAY) * np.ones(p)
    elif name == "payload" and p == 10:  # mass, first moments, inertia about the joint-7 origin
        m = MAX_PAYLOAD
        sd = _half(np.array([m] + [m * PAYLOAD_REACH] * 3 + [m * PAYLOAD_REACH ** 2] * 6))
    elif name == "link_mass":
        sd = _half(1.0) * np.ones(p)  # scales within [0.25, 2]: a change of at most +-1
    elif name == "gravity_tilt" and p == 3:
        g0 = np.asarray(ctx.config.gravity, dtype=float)
        u = g0 / max(float(np.linalg.norm(g0)), 1e-12)
        h = float(_half(np.linalg.norm(g0) * math.sin(MAX_TILT)))
        v = float(_half(G_MAGNITUDE_RANGE))
        return h ** 2 * (np.eye(3) - np.outer(u, u)) + v ** 2 * np.outer(u, u)
    elif name in ("link_inertials", "arm_link_inertials"):
        sd = _link_sd(e, ctx, p)
        if sd is None:
            return None
    else:
        return None
    return np.diag(np.asarray(sd, dtype=float) ** 2)


def _link_sd(e, ctx: Context, p: int) -> np.ndarray | None:
    """The link inertials' base parameters (standard columns of links 1-7: mass, first moments, inertia): each link's
    mass within ``LINK_SHARE`` of the model's, its first moments within that share of the mass times
    ``LINK_REACH``, its inertia within it times ``LINK_REACH``^2. A flange body (``payload``, up to the rated 3.5 kg
    and 0.3 m) is then the likelier explanation of a change at the flange than the links': the prior prefers it."""
    try:
        cols = e.basis(ctx.config)["cols"]
    except Exception:
        return None
    if len(cols) != p:
        return None
    m = np.maximum(np.abs(ctx.link_params[:, 0]), 0.1)
    body = ctx.config.flange_body()
    m = m.copy()
    m[6] += max(float(body.mass), 0.0)
    link, kind = np.asarray(cols) // 10, np.asarray(cols) % 10
    scale = np.where(kind == 0, 1.0, np.where(kind < 4, LINK_REACH, LINK_REACH ** 2))
    return _half(LINK_SHARE * m[link] * scale)


@dataclass
class Unit:
    """A per-joint law on one joint, or a shared effect (or a term the caller forces): the columns it adds."""

    effect: Effect
    shape: dict
    joint: int | None  # None: shared
    cols: slice
    forced: bool = False

    @property
    def name(self) -> str:
        return self.effect.name


def _smooth_1d(x: np.ndarray, m: int) -> np.ndarray:
    """Moving average over 2 m + 1 bins (edges reflected), as the spectrum is smoothed."""
    if m == 0 or len(x) < 2:
        return x.copy()
    ext = np.concatenate([x[1:m + 1][::-1], x, x[-m - 1:-1][::-1]])
    c = np.cumsum(np.concatenate([[0.0], ext]))
    w = 2 * m + 1
    out = (c[w:] - c[:-w]) / w
    return out[:len(x)] if len(out) >= len(x) else np.pad(out, (0, len(x) - len(out)), mode="edge")


def rescaled(nm: NoiseModel, factor: np.ndarray) -> NoiseModel:
    """``nm`` with its spectrum multiplied by ``factor`` (K,) per bin."""
    from dataclasses import replace

    f = np.asarray(factor, dtype=float)
    P = nm.P * f[:, None, None]
    return replace(nm, P=P, W=nm.W / f[:, None, None], logdet=nm.logdet + 7 * np.log(f))


def _whitened(nm: NoiseModel, cols: np.ndarray, y: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """The band of ``cols`` (n, 7, P) and ``y`` (n, 7), any length n, whitened by ``nm``'s spectrum at the nearest
    of its frequencies and stacked real: (R, P), (R,)."""
    n = len(y)
    f = np.fft.rfftfreq(n, 1.0 / fs)
    k = np.nonzero((f >= nm.freqs[0]) & (f <= nm.freqs[-1]))[0]
    near = np.clip(np.searchsorted(nm.freqs, f[k]), 0, len(nm.freqs) - 1)
    W = nm.W[near]
    L = np.linalg.cholesky(W)
    LH = np.conj(np.transpose(L, (0, 2, 1)))
    ak = (np.fft.rfft(cols, axis=0) / math.sqrt(n))[k]
    yk = (np.fft.rfft(y, axis=0) / math.sqrt(n))[k]
    wa = LH @ ak
    wy = np.einsum("kab,kb->ka", LH, yk)
    real = (k == 0) | ((n % 2 == 0) & (k == n // 2))
    c = np.sqrt(np.where(real, 1.0, 2.0))[:, None]
    p = cols.shape[2]
    X = np.concatenate([(c[:, :, None] * wa.real).reshape(-1, p), (c[:, :, None] * wa.imag).reshape(-1, p)])
    Y = np.concatenate([(c * wy.real).ravel(), (c * wy.imag).ravel()])
    return X, Y


def _temperature(cols: np.ndarray, y: np.ndarray, eng: Engine, nm: NoiseModel, units: list, fs: float) -> float:
    """How much more the units' estimates differ between the engine's contiguous blocks than the noise model says:
    every unit fitted jointly on each block (the reference set's Whittle estimate and variances there), Cochran's Q
    of each coefficient over the F blocks divided by its F - 1 degrees of freedom, the median over all coefficients
    (at least 1). A model error of the robot that follows the pose is not stationary noise: the units would take
    different shares of it in different parts of the motion, which the spread between blocks shows."""
    blocks = [np.asarray(b) for b in eng.folds if len(b) >= 16]
    if len(blocks) < 3:
        return 1.0
    est, var = [], []
    for b in blocks:
        X, Y = _whitened(nm, cols[b], y[b], fs)
        G = X.T @ X
        d = np.sqrt(np.maximum(np.diag(G), 1e-300))
        Gi = np.linalg.pinv(G / np.outer(d, d), hermitian=True, rcond=1e-8) / np.outer(d, d)
        est.append(Gi @ (X.T @ Y))
        var.append(np.diag(Gi))
    est, var = np.array(est), np.maximum(np.array(var), 1e-300)
    ok = np.all(np.isfinite(est), axis=0) & np.all(var < 1e290, axis=0)
    w = 1.0 / var[:, ok]
    mean = np.sum(w * est[:, ok], axis=0) / np.sum(w, axis=0)
    q = np.sum(w * (est[:, ok] - mean) ** 2, axis=0) / (len(blocks) - 1)
    return float(max(np.median(q), 1.0)) if q.size else 1.0


def _flange_split(effects: list[Effect], forced: list[Term]) -> list[Effect]:
    """With a flange body among the candidates (or forced), the link inertials are those of links 1-6: link 7's own
    parameters and a body held at the flange are one body to the joint torques, and it is named ``payload``."""
    from franka_vs_gym.validation.effects.inertial import ArmLinkInertials, LinkInertials

    if not any(e.name == "payload" for e in effects) and not any(t.effect.name == "payload" for t in forced):
        return effects
    return [ArmLinkInertials(e) if isinstance(e, LinkInertials) and not isinstance(e, ArmLinkInertials) else e
            for e in effects]


class Library:
    """Every unit's whitened columns in the motion band of one log, their Gram matrix and the target's, under the
    noise model of the generous reference fit: any set's evidence is a small solve."""

    def __init__(self, ctx: Context, eng: Engine, effects: list[Effect], forced: list[Term] = ()) -> None:
        self.ctx, self.eng = ctx, eng
        y = eng.y
        n = len(y)
        units: list[Unit] = []
        designs = []
        pos = 0
        for t in forced:
            D = eng.design(t)
            js = (t.joints or []) if t.effect.per_joint else [None]
            for j in js:
                units.append(Unit(t.effect, t.shape, j, slice(pos, pos + D.shape[2]), True))
                pos += D.shape[2]
            designs.append((t.effect, t.shape, D, js))
        forced_names = {t.effect.name for t in forced}
        effects = _flange_split(effects, forced)
        for e in effects:
            if e.name in forced_names:
                continue
            try:
                shape = e.shape(ctx, y)
                D = eng.design(Term(e, shape, list(range(7)) if e.per_joint else None))
            except Exception:  # an effect that cannot describe this log is no candidate here
                continue
            js = list(range(7)) if e.per_joint else [None]
            for j in js:
                units.append(Unit(e, shape, j, slice(pos, pos + D.shape[2])))
                pos += D.shape[2]
            designs.append((e, shape, D, js))
        self.units = units
        # time-domain columns (N, 7, P) of every unit: the reference fit and the transforms
        cols = np.zeros((n, 7, pos))
        k = 0
        for _, _, D, js in designs:
            p = D.shape[2]
            for j in js:
                if j is None:
                    cols[:, :, k:k + p] = D
                else:
                    cols[:, j, k:k + p] = D[:, j, :]
                k += p
        st = ctx.data.settings
        fs = float(st.rate)
        band = (0.0, float(st.cutoff)) if st.cutoff and st.cutoff < fs / 2 else None
        # the generous reference fit: every unit at once, least squares over every sample (column-scaled)
        a2 = cols.reshape(n * 7, pos)
        info = a2.T @ a2
        sc = np.sqrt(np.maximum(np.diag(info), 0.0))
        sc[sc == 0] = 1.0
        info = info / np.outer(sc, sc)
        info_inv = np.linalg.pinv(0.5 * (info + info.T), hermitian=True, rcond=1e-10)
        theta = info_inv @ ((a2.T @ y.reshape(n * 7)) / sc) / sc
        resid = y - (a2 @ theta).reshape(n, 7)
        hw = min(HALF_WIDTH, max(1, n // 8 - 1))
        nm = noise_model(resid, fs, band, hw)
        ak = nm.dft(cols)  # (K, 7, P)
        # the reference fit removes the noise along its own columns: bin k keeps the share 1 - h_k of it (h_k its
        # leverage per joint, from the time-domain least squares written in the frequency domain: sum_k A_k^H A_k
        # over both halves of the spectrum). The spectrum is divided by that share, smoothed as the periodogram is
        akn = ak / sc
        # (sum over the whole spectrum of A_k^H A_k is the time-domain Gram matrix, Parseval: info above)
        lev = np.real(np.einsum("kap,pq,kaq->k", np.conj(akn), info_inv, akn)) * np.where(nm.real, 1.0, 2.0) / 7
        keep = np.clip(1.0 - _smooth_1d(lev, hw), 0.2, 1.0)
        nm = rescaled(nm, 1.0 / keep)
        self.noise = nm
        yk = nm.dft(y)  # (K, 7)
        # whitening: W = L L^H (Cholesky of the inverse spectrum); z = L^H r has identity covariance per bin
        L = np.linalg.cholesky(nm.W)
        LH = np.conj(np.transpose(L, (0, 2, 1)))
        wa = LH @ ak
        wy = np.einsum("kab,kb->ka", LH, yk)
        # l = -sum_k c_k/2 |z_k|^2 with c_k = 2 inside the spectrum, 1 at its real bins (estimation.NoiseModel)
        c = np.sqrt(np.where(nm.real, 1.0, 2.0))[:, None]
        X = np.concatenate([(c[:, :, None] * wa.real).reshape(-1, pos), (c[:, :, None] * wa.imag).reshape(-1, pos)])
        Y = np.concatenate([(c * wy.real).ravel(), (c * wy.imag).ravel()])
        # the likelihood's temperature: how much more the units' estimates differ between the log's blocks than
        # the noise model says (1: as it says); the log-likelihood is divided by it
        self.kappa = _temperature(cols, y, eng, nm, units, fs) if TEMPERED else 1.0
        X, Y = X / math.sqrt(self.kappa), Y / math.sqrt(self.kappa)
        self.X, self.Y = X, Y  # the whitened band (kept: the tests recompute the evidence from them)
        self.G = X.T @ X
        self.b = X.T @ Y
        self.yy = float(Y @ Y)
        # prior covariance, block by unit (None: flat)
        self.prior: list[np.ndarray | None] = []
        for u in units:
            p = u.cols.stop - u.cols.start
            self.prior.append(None if u.forced else prior_cov(u.effect, ctx, p, u.joint))
        self._cache: dict[frozenset, float] = {}

    @property
    def log_prior_odds(self) -> float:
        """ln(pi / (1 - pi)) of one unit, pi = 1 / M of the M candidate units: a priori one effect among them is
        expected (each further unit tried is an alternative: this is the correction for trying them)."""
        m = sum(not u.forced for u in self.units)
        return -math.log(max(m - 1, 1))

    def log_posterior(self, members: frozenset[int]) -> float:
        """ln Z of the set plus its prior on sets (independent inclusion, pi = 1 / M): the criterion's score."""
        k = sum(not self.units[i].forced for i in members)
        return self.log_evidence(members) + k * self.log_prior_odds

    def log_evidence(self, members: frozenset[int]) -> float:
        """ln Z of the set of units ``members`` (forced units always in), up to a constant common to all sets."""
        key = frozenset(members) | frozenset(i for i, u in enumerate(self.units) if u.forced)
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        idx = sorted(key)
        if not idx:
            self._cache[key] = 0.0
            return 0.0
        ii = np.concatenate([np.arange(self.units[i].cols.start, self.units[i].cols.stop) for i in idx])
        G = self.G[np.ix_(ii, ii)]
        b = self.b[ii]
        P = len(ii)
        S = np.zeros((P, P))
        flat = np.zeros(P, dtype=bool)
        pos = 0
        for i in idx:
            p = self.units[i].cols.stop - self.units[i].cols.start
            if self.prior[i] is None:
                flat[pos:pos + p] = True
            else:
                S[pos:pos + p, pos:pos + p] = self.prior[i]
            pos += p
        # posterior precision G + S^-1 (flat coefficients: G alone); the evidence in the form that needs no S^-1:
        # with R = S^1/2, ln det(I + R G R) and b^T R (I + R G R)^-1 R b for the priored part
        lz = 0.0
        if flat.any():
            # profile the flat coefficients out (their Occam factor is common to every set that holds them)
            f = np.nonzero(flat)[0]
            g_ff = G[np.ix_(f, f)]
            d = np.sqrt(np.maximum(np.diag(g_ff), 1e-300))
            g_inv = np.linalg.pinv(g_ff / np.outer(d, d), hermitian=True) / np.outer(d, d)
            r = np.nonzero(~flat)[0]
            g_rf = G[np.ix_(r, f)]
            lz += 0.5 * float(b[f] @ g_inv @ b[f])
            b = b[r] - g_rf @ (g_inv @ b[f])
            G = G[np.ix_(r, r)] - g_rf @ g_inv @ g_rf.T
            S = S[np.ix_(r, r)]
        if len(b):
            w, V = np.linalg.eigh(S)
            R = (V * np.sqrt(np.maximum(w, 0.0))) @ V.T
            M = np.eye(len(b)) + R @ G @ R
            M = 0.5 * (M + M.T)
            cf = np.linalg.cholesky(M)
            rb = R @ b
            z = np.linalg.solve(cf, rb)
            lz += 0.5 * float(z @ z) - float(np.sum(np.log(np.diag(cf))))
        self._cache[key] = lz
        return lz


class EvidenceSelector:
    """The selection of ``diagnose`` by one criterion (:data:`LOG_RATIO` on the evidence), with the interface the
    diagnosis reads: :meth:`run`, :meth:`describe`, :meth:`ambiguities` and ``rejections``."""

    def __init__(self, ctx: Context, eng: Engine, noise: np.ndarray, effects: list[Effect], verbose: bool = False,
                 max_steps: int = 40) -> None:
        self.ctx, self.eng, self.noise, self.effects, self.verbose = ctx, eng, noise, effects, verbose
        self.max_steps = max_steps
        self.rejections: dict[str, str] = {}
        self.lib: Library | None = None
        self.members: frozenset[int] = frozenset()

    # --- the search
    def _search(self, lib: Library) -> frozenset[int]:
        cand = [i for i, u in enumerate(lib.units) if not u.forced]
        cur: frozenset[int] = frozenset()
        z = lib.log_posterior(cur)
        seen = {cur}
        for _ in range(self.max_steps):
            gains = [(lib.log_posterior(cur | {i}) - z, i) for i in cand if i not in cur]
            if not gains:
                break
            g, best = max(gains)
            if g <= LOG_RATIO:
                break
            cur = cur | {best}
            z = lib.log_posterior(cur)
            while len(cur) > 1:  # backward: the weakest unit whose removal costs less than ln B leaves
                losses = [(z - lib.log_posterior(cur - {i}), i) for i in cur]
                loss, worst = min(losses)
                if loss >= LOG_RATIO or (cur - {worst}) in seen:
                    break
                cur = cur - {worst}
                z = lib.log_posterior(cur)
            if cur in seen:
                break
            seen.add(cur)
        return cur

    def _terms(self, lib: Library, members: frozenset[int], forced: list[Term]) -> list[Term]:
        """The selected units as terms (a per-joint law with its joints), forced terms first, then in library
        order."""
        out = list(forced)
        by_effect: dict[str, list[int]] = {}
        order: list[str] = []
        for i in sorted(members):
            u = lib.units[i]
            if u.name not in by_effect:
                by_effect[u.name] = []
                order.append(u.name)
            if u.joint is not None:
                by_effect[u.name].append(u.joint)
        for name in order:
            u = next(lib.units[i] for i in sorted(members) if lib.units[i].name == name)
            out.append(Term(u.effect, u.shape, sorted(by_effect[name]) if u.effect.per_joint else None))
        return out

    def run(self, select: bool, max_effects: int | None = None, forced: list[Term] | None = None,
            ) -> tuple[list[Candidate], list[Term], SetFit]:
        forced = list(forced or [])
        lib = Library(self.ctx, self.eng, self.effects, forced)
        self.lib, self.forced = lib, forced
        ranking = self._ranking(lib, forced)
        members = self._search(lib) if select else frozenset()
        self.members = members
        chosen = self._terms(lib, members, forced)
        return ranking, chosen, self.eng.fit(chosen)

    def _ranking(self, lib: Library, forced: list[Term]) -> list[Candidate]:
        """Each effect alone beside the forced terms: its evidence (on the joints where it gains more than ln B)."""
        z0 = lib.log_posterior(frozenset())
        base_fit = self.eng.fit(forced)
        out = []
        for e in {lib.units[i].effect.name: lib.units[i].effect for i in range(len(lib.units))
                  if not lib.units[i].forced}.values():
            idx = [i for i, u in enumerate(lib.units) if u.effect is e]
            js = np.zeros(7)
            if e.per_joint:
                for i in idx:
                    js[lib.units[i].joint] = lib.log_posterior(frozenset({i})) - z0
                keep = [i for i in idx if js[lib.units[i].joint] > LOG_RATIO]
                joints = sorted(lib.units[i].joint for i in keep)
                score = (lib.log_posterior(frozenset(keep)) - z0) if keep else float(min(js.max(), 0.0))
                term = Term(e, lib.units[idx[0]].shape, joints or list(range(7)))
            else:
                score = lib.log_posterior(frozenset(idx)) - z0
                joints = []
                term = Term(e, lib.units[idx[0]].shape)
            sf = self.eng.fit(forced + [term])
            removed = np.sqrt(np.maximum(base_fit.mse_cv - sf.mse_cv, 0.0))
            if not e.per_joint:
                joints = [j for j in range(7) if removed[j] > 0]
                js = np.where(removed > 0, removed, 0.0)
            fit = sf.fits[-1]
            significant = bool(score > LOG_RATIO)
            problems = [f"{e.name}: {m}" for m in e.problems(self.ctx, fit).values()] if significant else []
            params = e.public(fit)
            t = e.tilt_deg(self.ctx, fit)
            if t is not None:
                params["tilt_deg"] = round(t, 4)
            out.append(Candidate(e.name, [e.name], joints, params, np.sqrt(sf.mse_cv), float(score), significant,
                                 not problems, problems, removed, js, [fit], [term], sf.mse_cv))
            if significant and problems:
                self.rejections.setdefault(e.name, "; ".join(problems))
        return sorted(out, key=lambda c: (not c.ok, not c.plausible, -c.score))

    # --- what the diagnosis reads
    def _unit_sets(self, chosen: list[Term]) -> dict[int, frozenset[int]]:
        """Term index -> the library units it holds."""
        lib = self.lib
        out = {}
        for k, t in enumerate(chosen):
            out[k] = frozenset(i for i, u in enumerate(lib.units) if not u.forced and u.effect is t.effect
                               and (u.joint is None or u.joint in (t.joints or [])))
        return out

    def describe(self, chosen: list[Term], cur: SetFit) -> list[Selected]:
        """Each selected effect: its joints, values, what it removes (held-out RMS) and its evidence in the whole set
        (the fall of ln Z without it)."""
        lib = self.lib
        units = self._unit_sets(chosen)
        z = lib.log_posterior(self.members)
        out = []
        for k, t in enumerate(chosen):
            rest = chosen[:k] + chosen[k + 1:]
            sf = self.eng.fit(rest)
            contrib = np.sqrt(np.maximum(sf.mse_cv - cur.mse_cv, 0.0))
            loss = z - lib.log_posterior(self.members - units[k]) if units[k] else float("inf")
            fit = cur.fits[k]
            params = t.effect.public(fit)
            tilt = t.effect.tilt_deg(self.ctx, fit)
            if tilt is not None:
                params["tilt_deg"] = round(tilt, 4)
            joints = list(t.joints) if t.effect.per_joint else [j for j in range(7) if contrib[j] > 0]
            out.append(Selected(t.effect.name, joints, params, contrib, float(loss) if math.isfinite(loss) else 0.0))
        return out

    def ambiguities(self, chosen: list[Term], cur: SetFit) -> list[Ambiguity]:
        """Sets within ``ln B`` of the selected one that put another effect in a selected unit's place: the two are
        reported ambiguous on the unit's joints (at most two alternatives per unit, the closest)."""
        from franka_vs_gym.validation.diagnose import CONFUSABLE

        lib = self.lib
        z = lib.log_posterior(self.members)
        found: dict[tuple[str, str], list[tuple[int | None, float, float]]] = {}
        for i in sorted(self.members):
            u = lib.units[i]
            rest = self.members - {i}
            z_rest = lib.log_posterior(rest)
            alts = []
            for v, w in enumerate(lib.units):
                if w.forced or v in self.members or w.name == u.name:
                    continue
                if u.joint is not None and w.joint is not None and w.joint != u.joint:
                    continue
                if u.joint is None and w.joint is not None:
                    continue
                if any(lib.units[m].name == w.name and (w.joint is None or lib.units[m].joint == w.joint)
                       for m in rest):
                    continue
                za = lib.log_posterior(rest | {v})
                if za > z - LOG_RATIO and za - z_rest > LOG_RATIO:
                    alts.append((za, w))
            for za, w in sorted(alts, key=lambda a: -a[0])[:2]:
                found.setdefault((u.name, w.name), []).append((u.joint, z - z_rest, za - z_rest))
        out = []
        for (a, b), rows in found.items():
            joints = sorted({r[0] for r in rows if r[0] is not None}) or list(range(7))
            why = next((s for n, s in CONFUSABLE.get(a, []) if n == b), SEPARATE)
            out.append(Ambiguity([a, b], joints, {a: round(sum(r[1] for r in rows), 2),
                                                  b: round(sum(r[2] for r in rows), 2)}, why))
        return out
