"""Confidence on every fitted number: standard errors, 95 % intervals, strong correlations and unidentifiable
combinations of the parameters ``diagnose`` selects and ``fit`` applies.
**Noise model.** The covariance of the parameters is the sandwich of :mod:`~franka_vs_gym.validation.covariance`
(equal-weighted cosine and spectral estimates, the wider kept parameter by parameter; see its docstring for the noise
model and why).

**Non-linear parameters.** Every fitted number of an effect (its linear coefficients and the shape parameters of
its law: the sigmoid's width and centre, the Coulomb smoothing velocity, a refined delay, the replacement sigmoid of
``fit``) is a parameter of the Jacobian ``J = d(contribution)/d(theta)`` (central finite differences of the effect's
own ``contribution``; exact for the linear ones), so the sandwich is the delta method of the non-linear least-squares
fit. Reported quantities that are non-linear functions of these (payload mass, centre of mass and inertia from the
ten dynamic parameters, the tilt angle from the gravity change) get their interval by propagating ``N(theta,
Sigma)`` through the effect's own ``public`` (``N_DRAWS`` seeded draws; the interval is the value +- the Student
quantile times the draws' standard deviation); numbers ``public`` reports linearly (a friction coefficient, an
armature, an offset: checked by finite differences and two probe draws) get ``sqrt(g^T Sigma g)`` exactly instead.
No effect needs code of its own, plug-ins included.

**Unidentifiable directions.** Eigen-directions of the column-scaled ``J^T J`` below ``NULL_TOL`` of the largest
are not identified by the log. Every reported number that moves along one gets the interval ``None``, and the
combination is said in words ("payload mass and link 7 mass scale: only their sum is seen").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy import stats

from franka_vs_gym.validation.covariance import (
    NULL_TOL,
    Covariance,
    covariance,
    ewc_dof,
    parameter_covariance,
)

if TYPE_CHECKING:
    from franka_vs_gym.validation.effects import Context, Fit
    from franka_vs_gym.validation.results import Selected
    from franka_vs_gym.validation.selection import SetFit, Term

CORR_MIN = 0.9  # |r| above which a pair of parameters is reported as correlated
N_DRAWS = 500
_SKIP_KEYS = {"replace", "links", "joints"}


# ------------------------------------------------------------------------------------- effects' parameters
def _leaf_paths(obj: Any, path: tuple = ()) -> list[tuple]:
    """Paths of the numeric leaves of a JSON-like structure."""
    out: list[tuple] = []
    if isinstance(obj, dict):
        for k, v in obj.items():
            if k in _SKIP_KEYS:
                continue
            out += _leaf_paths(v, path + (k,))
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            out += _leaf_paths(v, path + (i,))
    elif isinstance(obj, (float, np.floating)):  # integers (counts, indices) are not estimates
        out.append(path)
    return out


def _get(obj: Any, path: tuple) -> float | None:
    try:
        for k in path:
            obj = obj[k]
    except (KeyError, IndexError, TypeError):
        return None
    if obj is None or isinstance(obj, (bool, str)):
        return None
    try:
        v = float(obj)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _set(obj: Any, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        obj = obj[k]
    obj[path[-1]] = value


def _mirror(obj: Any) -> Any:
    """The structure with every number replaced by None; strings, booleans and the ``joints`` list kept."""
    if isinstance(obj, dict):
        return {k: (v if k in _SKIP_KEYS else _mirror(v)) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_mirror(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return None
    return obj


_PAYLOAD = ["mass", "first moment x", "first moment y", "first moment z", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz"]


def _label(effect, key: str, idx: tuple, joints_shape: bool) -> str:
    name = effect.name
    if key == "coef":
        if name == "payload":
            return f"payload {_PAYLOAD[idx[0]]}"
        if name == "gravity_tilt":
            return f"gravity {'xyz'[idx[0]]}"
        if name == "link_mass":
            return f"link {idx[0] + 1} mass scale"
        if name == "link_inertials":
            return f"arm base parameter {idx[0]}"
        if name in ("delay",):
            return "delay"
        if joints_shape:
            col = f" (column {idx[1]})" if len(idx) > 1 and idx[1] > 0 else ""
            return f"{name} joint {idx[0]}{col}"
        return f"{name} coefficient {idx[0]}"
    if joints_shape:
        return f"{name} {key} joint {idx[0]}"
    return f"{name} {key}" + (f" {idx[0]}" if idx and len(idx) else "")


@dataclass
class _Param:
    term: int
    key: str
    idx: tuple
    label: str
    value: float
    step: float


def _theta_params(effect, fit, ti: int) -> list[_Param]:
    out: list[_Param] = []
    for key, v in fit.theta.items():
        if key in _SKIP_KEYS or isinstance(v, (bool, str)) or v is None:
            continue
        try:
            a = np.asarray(v, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if a.dtype.kind not in "fiu" or a.size == 0:
            continue
        joints_shape = effect.per_joint and a.ndim >= 1 and a.shape[0] == 7
        if key == "coef" and effect.per_joint:
            a = a.reshape(7, -1)
            joints_shape = True
        for idx in np.ndindex(a.shape):
            if joints_shape and idx[0] not in fit.joints:
                continue
            val = float(a[idx])
            step = 1e-4 * max(abs(val), 1e-3) if key != "coef" else 1.0
            out.append(_Param(ti, key, tuple(int(i) for i in idx), _label(effect, key, idx, joints_shape), val, step))
    return out


def _with(fit, p: _Param, value: float):
    """A copy of ``fit`` with the one parameter ``p`` set to ``value``."""
    return _set_theta(fit, [p], [value])


def _set_theta(fit, params: list[_Param], x: np.ndarray):
    """A copy of ``fit`` with the parameters ``params`` (all of this fit) set to ``x``."""
    from franka_vs_gym.validation.effects import Fit

    th = {k: (np.array(v, dtype=np.float64, copy=True) if k in {p.key for p in params} else v)
          for k, v in fit.theta.items()}
    for p, v in zip(params, x, strict=True):
        a = th[p.key]
        if p.key == "coef" and a.ndim == 1 and len(p.idx) == 2:
            a = a.reshape(7, -1)
            th[p.key] = a
        if a.ndim == 0:
            th[p.key] = np.float64(v)
        else:
            a[p.idx] = v
    return Fit(fit.effect, th, list(fit.joints))


def _public(effect, ctx, fit) -> dict[str, Any]:
    out = effect.public(fit)
    t = effect.tilt_deg(ctx, fit)
    if t is not None:
        out["tilt_deg"] = t
    return out


@dataclass
class Confidence:
    """The confidence of a set of fitted effects: per effect ``params_ci95`` (same structure as its ``public``
    parameters, numbers replaced by [low, high] or None), ``correlations`` (|r| > CORR_MIN pairs) and
    ``unidentifiable`` (sentences), plus the parameter-level covariance."""

    params_ci95: list[dict[str, Any]]
    correlations: list[list[dict[str, Any]]]
    unidentifiable: list[list[str]]
    labels: list[str]
    theta: np.ndarray
    cov: Covariance
    #: (P,) the first-order bias of each parameter from the acceleration's noise (see :func:`inertial_bias`) plus, for
    #: a delay fitted on a low-rate log, what linear interpolation adds to it (:func:`interpolation_bias`); every
    #: interval also covers the number corrected by it
    bias: np.ndarray | None = None


def _words(null: np.ndarray, labels: list[str], scale: np.ndarray) -> list[str]:
    out = []
    for c in range(null.shape[1]):
        u = null[:, c]
        us = u * scale
        idx = [i for i in np.argsort(-np.abs(us)) if abs(us[i]) > 0.15 * np.abs(us).max()]
        if not idx:
            continue
        if len(idx) == 1:
            out.append(f"{labels[idx[0]]}: not seen at all by this log")
            continue
        if len(idx) == 2:
            a, b = idx
            r = u[a] / u[b]
            if abs(r + 1) < 0.05:
                how = "only their sum is seen"
            elif abs(r - 1) < 0.05:
                how = "only their difference is seen"
            else:  # the seen combination A u_b - B u_a, i.e. A - (u_a / u_b) B
                k = -u[a] / u[b]
                how = f"only {labels[a]} {'+' if k >= 0 else '-'} {abs(k):.3g} x {labels[b]} is seen"
            out.append(f"{labels[a]} and {labels[b]}: {how}")
            continue
        names = ", ".join(labels[i] for i in idx[:-1]) + f" and {labels[idx[-1]]}"
        steps = ", ".join(f"{u[i] / abs(u[idx[0]]):+.3g}" for i in idx)
        out.append(f"{names}: the log cannot tell them apart (changing them together by {steps} x leaves every "
                   "torque unchanged)")
    return out


def confidence(ctx, effects: list, fits: list, y: np.ndarray, *, method: str = "hac",
               draws: int = N_DRAWS, seed: int = 0) -> Confidence:
    """Intervals of every reported parameter of the jointly fitted ``effects`` / ``fits`` on target ``y`` (N, 7)
    (the context's residual the set explains); see the module docstring."""
    params: list[_Param] = []
    for ti, (e, f) in enumerate(zip(effects, fits, strict=True)):
        params += _theta_params(e, f, ti)
    from franka_vs_gym.validation.effects import Effect

    contrib = [e.contribution(ctx, f) for e, f in zip(effects, fits, strict=True)]
    resid = y - sum(contrib, np.zeros_like(y))
    P = len(params)
    n = ctx.n
    Jt = np.zeros((P, n, 7))  # d(contribution)/d(theta_k), one contiguous block per parameter
    designs: dict[int, np.ndarray] = {}
    unfitted = np.zeros(P, dtype=bool)
    for k, p in enumerate(params):
        e, f = effects[p.term], fits[p.term]
        if p.key == "coef" and p.term not in designs:
            designs[p.term] = e.design(ctx, {kk: v for kk, v in f.theta.items() if kk != "coef"})
        if p.key == "coef" and e.per_joint and len(p.idx) > 1 and p.idx[1] >= designs[p.term].shape[2]:
            unfitted[k] = True  # a coefficient the effect's design has no column for (not estimated)
            continue
        if p.key == "coef" and type(e).contribution is Effect.contribution:  # linear: the design's column
            D = designs[p.term]
            if e.per_joint:
                Jt[k, :, p.idx[0]] = D[:, p.idx[0], p.idx[1] if len(p.idx) > 1 else 0]
            else:
                Jt[k] = D[:, :, p.idx[0]]
        elif p.key == "coef":
            Jt[k] = e.contribution(ctx, _with(f, p, p.value + 1.0)) - contrib[p.term]
        else:
            h = p.step
            Jt[k] = (e.contribution(ctx, _with(f, p, p.value + h))
                     - e.contribution(ctx, _with(f, p, p.value - h))) / (2 * h)
    Jf = Jt.reshape(P, -1)
    # a parameter is fitted when changing it (a coefficient by 1, a shape parameter by its own size) changes the
    # torque by more than round-off: e.g. the scale of a model term the model does not have is not
    ref = np.array([1.0 if p.key == "coef" else max(abs(p.value), 1e-3) for p in params])
    live = (np.linalg.norm(Jf, axis=1) * ref > 1e-7 * max(float(np.linalg.norm(y)), 1e-12)) & ~unfitted
    labels = [p.label for p in params]
    if not live.any():  # nothing fitted (e.g. an effect without numeric parameters): every number unidentified
        pubs = [_public(e, ctx, f) for e, f in zip(effects, fits, strict=True)]
        return Confidence([_mirror(pb) for pb in pubs], [[] for _ in pubs], [[] for _ in pubs], labels,
                          np.array([p.value for p in params]), Covariance(np.zeros((P, P)), math.inf,
                                                                          np.zeros((P, 0)), np.ones(P), method))
    Jlive = Jt if live.all() else Jt[live]  # (no 30 MB copies when every parameter is fitted, the usual case)
    Jl = Jlive.reshape(len(Jlive), -1)
    gram = Jl @ Jl.T
    cv = covariance(Jlive.transpose(1, 2, 0), resid, method=method, gram=gram, nonzero=Jlive.any(axis=1).T)
    theta = np.array([p.value for p in params])
    bias = np.zeros(P)
    bias[live] = inertial_bias(ctx, effects, [params[k] for k in np.nonzero(live)[0]], gram)
    bias += interpolation_bias(ctx, effects, params, contrib, resid, live)
    # full-size covariance (dead parameters: not fitted, no column)
    full = np.zeros((P, P))
    li = np.nonzero(live)[0]
    full[np.ix_(li, li)] = cv.cov
    null = np.zeros((P, cv.null.shape[1]))
    null[li] = cv.null
    scale = np.ones(P)
    scale[li] = cv.scale
    cov_full = Covariance(full, cv.dof, null, scale, cv.method, cv.info)
    q = cv.quantile
    rng = np.random.default_rng(seed)
    # draws in the identified subspace
    w, V = np.linalg.eigh(cv.cov)  # the fitted parameters only: the others stay exactly at their value
    w = np.where(w > 1e-12 * max(float(w.max(initial=0.0)), 1e-300), w, 0.0)
    Z = np.zeros((draws, P))
    Z[:, li] = rng.standard_normal((draws, len(w))) @ (V * np.sqrt(w)).T
    ci, corr, unid = [], [], []
    se = cov_full.se()
    sentences = _words(null, labels, scale)
    for ti, (e, f) in enumerate(zip(effects, fits, strict=True)):
        pub = _public(e, ctx, f)
        mirror = _mirror(pub)
        paths = _leaf_paths(pub)
        own = [k for k, p in enumerate(params) if p.term == ti]
        # numbers that are linear in the parameters (a friction coefficient, an armature, an offset): their standard
        # deviation exactly, sqrt(g^T Sigma g); the others (payload mass and centre of mass, a tilt angle) by draws
        G = _linear_public(e, ctx, f, [params[k] for k in own], theta[own], Z[:2, own], pub, paths)
        vals: dict[tuple, list] = {pth: [] for pth in paths}
        if G is not None:
            C = full[np.ix_(own, own)]
            sd_lin = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", G, C, G), 0.0))
        for d in range(draws if G is None else 0):
            x = theta.copy()
            x[own] += Z[d, own]
            pd = _public(e, ctx, _set_theta(f, [params[k] for k in own], x[own]))
            for pth in paths:
                vals[pth].append(_get(pd, pth))
        # numbers that move along an unidentified direction
        moved: set[tuple] = set()
        for c in range(null.shape[1]):
            u = null[own, c]
            if not np.any(u):
                continue
            s_own = np.maximum(np.maximum(np.abs(theta[own]), se[own]), 1e-6)
            t = 1.0 / max(float(np.max(np.abs(u) / s_own)), 1e-300)
            for sgn in (1.0, -1.0):
                pd = _public(e, ctx, _set_theta(f, [params[k] for k in own], theta[own] + sgn * t * u))
                for pth in paths:
                    a, b = _get(pub, pth), _get(pd, pth)
                    if a is None or b is None or abs(b - a) > 1e-3 * (abs(a) + 1e-6):
                        moved.add(pth)
        b_leaf = pub_b = None
        if np.any(bias[own]):
            if G is not None:
                b_leaf = G @ bias[own]
            else:
                b_leaf = bias[own]
                pub_b = _public(e, ctx, _set_theta(f, [params[k] for k in own], theta[own] - bias[own]))
        for i_p, pth in enumerate(paths):
            v0 = _get(pub, pth)
            if G is not None:
                sd = float(sd_lin[i_p])
                if v0 is None or pth in moved or not sd > 0.0:  # None: unidentified, or nothing fitted drives it
                    continue
            else:
                vs = np.array([v for v in vals[pth] if v is not None], dtype=float)
                # None: moves along an unidentified direction, or does not move at all (nothing fitted drives it)
                if v0 is None or pth in moved or len(vs) < 0.9 * draws or float(np.ptp(vs)) == 0.0:
                    continue
                sd = float(np.std(vs))
            half = q * sd
            lo, hi = v0 - half, v0 + half
            if b_leaf is not None:  # the interval of the bias-corrected number joins it (see inertial_bias)
                vb = (v0 - float(b_leaf[i_p])) if G is not None else _get(pub_b, pth)
                if vb is not None:
                    lo, hi = min(lo, vb - half), max(hi, vb + half)
            _set(mirror, pth, [_r(lo), _r(hi)])
        if any(k in pub for k in ("link_mass_kg", "link_com_m")):
            sentences_own = ("link_inertials: single link masses and centres of mass are not identifiable from joint "
                             "torques, only the base parameters are (the link values shown are the physically "
                             "consistent arm closest to the published one)")
        else:
            sentences_own = None
        ci.append(mirror)
        # correlations among this effect's parameters and with the others'
        pairs = []
        for a in own:
            for b in range(P):
                if b == a or (b in own and b < a) or se[a] <= 0 or se[b] <= 0:
                    continue
                r = full[a, b] / (se[a] * se[b])
                if abs(r) > CORR_MIN:
                    pairs.append({"a": labels[a], "b": labels[b], "r": round(float(r), 3)})
        corr.append(pairs)
        names = {labels[k] for k in own}
        unid.append([s for s in sentences if any(nm in s for nm in names)] + ([sentences_own] if sentences_own else []))
    return Confidence(ci, corr, unid, labels, theta, cov_full, bias)


def inertial_bias(ctx, effects: list, params: list, gram: np.ndarray) -> np.ndarray:
    """(P,) the first-order bias of the jointly fitted ``params`` (their normal matrix ``gram``) that the noise of
    the acceleration puts into them (an errors-in-variables bias; zeros when there is none to speak of).

    The acceleration ``ddq`` is the derivative of the measured velocity; at low rates the velocity's broadband
    noise (a differentiated encoder, sampled without an anti-alias filter) is folded into the log's band, so ddq
    carries a noise ``e`` of standard deviation ``sigma_j`` (``ProcessedLog.ddq_noise``, estimated by the cleaning
    from the velocity's content above the cutoff). It enters twice: in the armature's regressor (``ddq_j``) and,
    through the baseline model's ``M(q) ddq``, in the residual the armature explains, with the opposite sign. With
    ``y = J theta - (M(q) + diag(I)) e + noise`` and ``J = J_true + e`` on an armature column, least squares gives
    ``E[theta_hat] - theta = (J^T J)^-1 c`` with ``c_k = -sigma_j^2 sum_t (M_jj(q_t) + I_j)`` for the armature
    coefficient ``k`` of joint ``j`` (``I_j`` the model's plus the fitted armature) and 0 elsewhere: the armature
    is pulled down by about ``(M_jj + I_j) sigma_j^2 / mean(ddq_j^2)``, a fraction of the link inertia ten times
    the armature's size, and the other parameters of the set by their correlation with it. ``sigma_j^2`` is taken
    at the upper 97.5 % bound of its chi-square estimate (``ProcessedLog.ddq_noise_dof``; about 1.3 times the
    estimate on 8 s at 30 Hz): the returned bias is the largest the log supports, and the intervals extend to it.
    Measured on generator B at 30 Hz: an armature fitted at 0.5-0.9 times the truth (down to -6 times on a joint
    that barely accelerates) on exact decimations of logs with 1 % of the torque noise
    (docs/workbench/evidence.md, "How sure")."""
    sig = getattr(ctx.data, "ddq_noise", None)
    out = np.zeros(len(params))
    arm = [k for k, p in enumerate(params) if p.key == "coef" and getattr(effects[p.term], "name", "") == "armature"]
    if sig is None or not arm:
        return out
    import pinocchio as pin

    from franka_vs_gym.model.franka_model import build_pinocchio_model

    model, _, _ = build_pinocchio_model(ctx.config)
    d = model.createData()
    sub = ctx.coarse  # M(q) changes slowly: the mean over the decimated samples
    mjj = np.mean([np.diag(pin.crba(model, d, ctx.data.q[i])) for i in sub], axis=0)  # armature included
    # the noise variance at its upper 97.5 % bound (the level is a chi-square estimate from the velocity's
    # periodogram): the bias grows with it, so the interval holds the correction the log allows at the most
    dof = float(getattr(ctx.data, "ddq_noise_dof", math.inf))
    up = dof / stats.chi2.ppf(0.025, dof) if math.isfinite(dof) else 1.0
    c = np.zeros(len(params))
    for k in arm:
        j = params[k].idx[0]
        c[k] = -up * float(sig[j]) ** 2 * ctx.n * (mjj[j] + params[k].value)
    if not np.any(c):
        return out
    scale = np.sqrt(np.maximum(np.diag(gram), 1e-300))
    Gs = gram / np.outer(scale, scale)
    w, V = np.linalg.eigh(0.5 * (Gs + Gs.T))
    ok = w > NULL_TOL * max(float(w[-1]), 1e-300)
    B = ((V[:, ok] / w[ok]) @ V[:, ok].T) / np.outer(scale, scale)
    return B @ c


def interpolation_bias(ctx, effects: list, params: list, contrib: list, resid: np.ndarray,
                       live: np.ndarray) -> np.ndarray:
    """(P,) for a fitted measurement delay on a log whose rate is too low for linear interpolation to shift the
    motion band exactly (:func:`effects.timing.linear_shift_exact`: 100 Hz and below with the default cutoffs):
    the fitted delay minus the delay the band-limited shift of the model's torque gives on the same residual (the
    delay's contribution plus what the set leaves; :func:`effects.timing.band_limited_delay`), zeros elsewhere.

    ``diagnose`` reports the delay of an exact-shift fit that interpolates the model's torque linearly. At 30 Hz
    the velocity noise the logger folds into the band rides on that torque, and linear interpolation keeps less of
    its power the nearer the shift falls to half a sample period, which pulls the fit there (on the hidden-effect
    generator's 7-12 ms delays at 30 Hz: 2.4-8 % above the noise-free fit with only the velocity noise,
    docs/workbench/evidence.md, "How sure"). As with :func:`inertial_bias`, the fitted value is kept and the
    interval also holds the corrected one."""
    from franka_vs_gym.validation.effects.timing import band_limited_delay, linear_shift_exact

    out = np.zeros(len(params))
    if linear_shift_exact(ctx.data.settings):
        return out
    for k, p in enumerate(params):
        e = effects[p.term]
        if not (live[k] and p.key == "coef" and getattr(e, "name", "") == "delay"
                and getattr(e, "channel", "") == "measurement" and p.value > 0):
            continue
        d = band_limited_delay(ctx, resid + contrib[p.term], p.value)
        if d is not None:
            out[k] = p.value - d
    return out


def _linear_public(effect, ctx, fit, own: list[_Param], theta: np.ndarray, probes: np.ndarray, pub: dict,
                   paths: list[tuple]) -> np.ndarray | None:
    """(leaves, own parameters) gradient of the effect's reported numbers when they are linear in its parameters
    (finite differences of a unit change of each coefficient, or its step for a shape parameter, then checked on
    the given probe draws: the linear prediction must hold to the rounding of ``public``), else None."""
    if not own or not paths:
        return None

    def leaves(x: np.ndarray) -> np.ndarray | None:
        out = [_get(_public(effect, ctx, _set_theta(fit, own, x)), pth) for pth in paths]
        return None if any(v is None for v in out) else np.array(out, dtype=float)

    v0 = [_get(pub, pth) for pth in paths]
    if any(v is None for v in v0):
        return None
    v0 = np.array(v0, dtype=float)
    G = np.empty((len(paths), len(own)))
    for i, p in enumerate(own):
        h = 1.0 if p.key == "coef" else p.step
        x = theta.copy()
        x[i] += h
        v = leaves(x)
        if v is None:
            return None
        G[:, i] = (v - v0) / h
    for z in probes:
        v = leaves(theta + z)
        lin = G @ z
        if v is None or np.any(np.abs(v - v0 - lin) > 2e-6 * (1 + np.abs(v0)) + 1e-3 * np.abs(lin)):
            return None
    return G


def _r(x: float) -> float:
    if x == 0 or not math.isfinite(x):
        return float(x)
    return float(f"{x:.6g}")


def format_value(v: Any, ci: Any) -> str:
    """'value [low, high]' for a number with its interval, 'value [not identifiable]' for None."""
    if isinstance(v, float):
        if isinstance(ci, (list, tuple)) and len(ci) == 2:
            return f"{v:.4g} [{ci[0]:.4g}, {ci[1]:.4g}]"
        return f"{v:.4g} [not identifiable]"
    return str(v)


def _fmt_list(v: list, c: Any, joints: list[int] | None = None) -> str:
    cl = c if isinstance(c, list) else [None] * len(v)
    items = []
    for i, (x, cc) in enumerate(zip(v, cl, strict=False)):
        if isinstance(x, list):
            items.append(_fmt_list(x, cc))
        elif x is None or (joints is not None and len(v) == 7 and i not in joints):
            items.append("-")
        else:
            items.append(format_value(x, cc))
    return "[" + "; ".join(items) + "]"


def format_params(params: dict[str, Any], ci: dict[str, Any] | None, joints: list[int] | None = None) -> str:
    """The parameters with their 95 % intervals, ``name=value [low, high]`` (lists element by element; per-joint
    lists show "-" for the joints the effect is not fitted on when ``joints`` is given)."""
    parts = []
    for k, v in params.items():
        c = (ci or {}).get(k)
        if isinstance(v, list):
            parts.append(f"{k}={_fmt_list(v, c, joints)}")
        elif isinstance(v, float):
            parts.append(f"{k}={format_value(v, c)}")
        else:
            parts.append(f"{k}={v}")
    return ", ".join(parts)


def attach_confidence(ctx: Context, y: np.ndarray, chosen: list[Term], cur: SetFit,
                       selection: list[Selected]) -> None:
    """Intervals, correlations and unidentifiable combinations of the jointly fitted selection
    (:mod:`~franka_vs_gym.validation.uncertainty`)."""
    try:
        conf = confidence(ctx, [t.effect for t in chosen], cur.fits, y)
    except Exception as exc:  # e.g. a plug-in whose contribution fails off its fitted values: keep the diagnosis
        for s in selection:
            s.unidentifiable = [f"intervals not computed: {type(exc).__name__}: {exc}"]
        return
    for s, ci, corr, unid in zip(selection, conf.params_ci95, conf.correlations, conf.unidentifiable, strict=True):
        s.params_ci95, s.correlations, s.unidentifiable = ci, corr, unid


def attach_command_confidence(ctx: Context, fit: Fit, s: Selected) -> None:
    """The interval of a delay fitted on the command channel (measured torque vs logged command)."""
    from franka_vs_gym.validation.effects import COMMAND_DELAY

    conf = confidence(ctx, [COMMAND_DELAY], [fit], ctx.cmd_residual)
    s.params_ci95, s.correlations, s.unidentifiable = (conf.params_ci95[0], conf.correlations[0],
                                                       conf.unidentifiable[0])


__all__ = ["Confidence", "Covariance", "attach_command_confidence", "attach_confidence", "confidence", "covariance",
           "covered", "ewc_dof", "format_params", "format_value", "parameter_covariance"]


def covered(ci: Any, truth: Any, joints: list[int] | None = None) -> tuple[int, int, int]:
    """(inside, outside, unidentified) counts of the true value(s) ``truth`` (a number or a list, per joint when
    ``joints`` is given: only those joints count) against the intervals ``ci`` (one ``params_ci95`` entry)."""
    if isinstance(truth, (int, float)):
        truth, ci, joints = [truth], [ci], None
    ins = out = unid = 0
    for j, (t, c) in enumerate(zip(truth, ci, strict=False)):
        if joints is not None and j not in joints:
            continue
        if c is None:
            unid += 1
        elif c[0] <= t <= c[1]:
            ins += 1
        else:
            out += 1
    return ins, out, unid
