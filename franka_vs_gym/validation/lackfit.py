"""Lack-of-fit test of every selected effect: does the named law capture the shape its own driving variable shows?

Selection picks the library effect that removes most of the residual, but a library law can absorb most of an effect
that is *not* in the library (a dead zone or backlash looks like a Coulomb step, a torque lag like a viscous line)
and leave only a small remainder that no generic structure test sees. A confident name is then wrong. This module
asks each selected effect a sharper question: along its **own driving variable(s)** (the variables its law says it
depends on, :meth:`Effect.lof_drivers`), is the *partial residual* ``p_j = r_j + c_j`` (the final residual plus the
effect's fitted contribution on joint j) described by the fitted law ``c_j``, or does a nonparametric function of
the same variables describe it better?

For every selected effect and every joint it acts on (with a contribution of practical size), the alternatives are
(each fitted by least squares together with a free multiple of ``c_j``, so the law itself is nested in each):

================  =================================================================================================
``shape``         piecewise-constant in ``N_BINS`` quantile bins of each driver (any smooth or stepped function of
                  it: a dead zone, a different rounding, a saturation, a hump)
``pose``          for laws whose step height is constant by definition (``Effect.lof_constant_height``): a
                  velocity-sign step whose height varies over ``N_POSE`` bins of the joint position and of the
                  joint's load torque (backlash against gravity, pose-dependent friction)
``lag``           the ``shape`` bins of the driver shifted in time by +-``LAGS_S`` (the residual follows the driver
                  late or early: a delay absorbed by an instantaneous law)
``drift``         the law with a coefficient that changes over the log, ``c_j (a + b P1(t) + c P2(t))`` (Legendre
                  polynomials of time): a physical constant of the law (a friction level, a viscosity, a mass, a
                  tilt) does not change within one log, so a law that fits only with a drifting coefficient stands in
                  for something else (friction changing as the joint warms, a slowly changing load or offset); a
                  coefficient that changes by more than ``DRIFT_RATIO`` (or changes sign) counts from
                  ``DRIFT_PRACTICAL`` noise floors
================  =================================================================================================

Statistic: the alternatives are judged on held-out data (the same interleaved 1 s blocks as the structure test), on
the residual decimated to about 250 Hz. The evidence ``N_eff ln(MSE_law / MSE_alt) - dk ln N_eff`` (``N_eff`` the
effective sample size of the residual under its autocorrelation, ``dk`` the extra parameters) must exceed
``SCORE_MIN + ln(m)`` (``m`` the number of (effect, joint, alternative) tests: a Bonferroni-like control across
joints and effects), **and** the alternative must remove an RMS of at least ``PRACTICAL`` times the joint's noise
floor: on a long log a deviation much smaller than the noise does not flip the verdict.

A failed test does not remove the effect: it stays in ``selected`` as the closest library effect, marked with
``lack_of_fit`` (the statistic, the joints, what the residual follows), and the diagnosis says ``explained: false``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from franka_vs_gym.validation.effects import Context
from franka_vs_gym.validation.results import Selected
from franka_vs_gym.validation.selection import Engine, SetFit, Term, n_eff
from franka_vs_gym.validation.structure import BLOCK_S, Finding, _bins, _cv_lin

SCORE_MIN = 10.0
PRACTICAL = 0.25
N_BINS = 12
N_POSE = 6
LAGS_S = (0.02, 0.04)
STEP_VEL = 0.02  # rad/s, smoothing of the velocity sign of the pose alternative
MIN_CONTRIB = 0.25  # noise floors: joints where the effect contributes less are not tested
DRIFT_PRACTICAL = 0.1  # noise floors: a drifting coefficient counts from this size when it changes by DRIFT_RATIO
DRIFT_RATIO = 1.5  # a law's coefficient changing by more than this factor over one log is no physical constant

WHAT = {"shape": "a different shape of {d} than the law's", "pose": "a step whose height depends on the pose/load",
        "lag": "{d} with a lag of {lag}", "drift": "the law with a coefficient that drifts over the log ({lag})"}


@dataclass
class LackOfFit:
    """One failed lack-of-fit test: effect, joint, alternative (``shape``, ``pose``, ``lag``), the driver, the RMS
    (Nm) the alternative removes beyond the law, the score and a detail."""

    effect: str
    joint: int
    alternative: str
    driver: str
    removed_rms: float
    score: float
    threshold: float
    detail: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"joint": self.joint, "alternative": self.alternative, "driver": self.driver,
                "removed_rms": round(self.removed_rms, 4), "score": round(self.score, 1),
                "threshold": round(self.threshold, 1), "detail": self.detail}


def _indicators(x: np.ndarray, n: int) -> np.ndarray:
    b = _bins(x, n)
    return (b[:, None] == np.arange(n)[None, :]).astype(float)


def test_lack_of_fit(ctx: Context, terms: list[Term], contributions: list[np.ndarray], residual: np.ndarray,
                     noise: np.ndarray, n_folds: int) -> dict[int, list[LackOfFit]]:
    """Lack-of-fit of each selected term (index -> failed tests, empty lists omitted); ``contributions`` are the
    terms' in-sample contributions (N, 7) Nm and ``residual`` the final residual (N, 7) Nm, all on ``ctx.data``."""
    data = ctx.data
    step = max(1, int(round(data.settings.rate / 250.0)))
    idx = np.arange(0, data.n, step)
    t = data.time[idx]
    fold = (np.floor((t - t[0]) / BLOCK_S).astype(int)) % n_folds
    jobs = []
    for i, (term, c) in enumerate(zip(terms, contributions, strict=True)):
        drivers = term.effect.lof_drivers(ctx) or {"its own contribution": c}
        for j in range(7):
            if not term.active(j):
                continue
            cj = c[idx, j]
            if math.sqrt(float(np.mean(cj ** 2))) < MIN_CONTRIB * noise[j] or np.ptp(cj) <= 0:
                continue
            jobs.append((i, j, drivers))
    alts = []
    for i, j, drivers in jobs:
        for name, x in drivers.items():
            alts.append((i, j, "shape", name, x[:, j], 0))
            for lag in LAGS_S:
                sh = int(round(lag * data.settings.rate))
                if sh >= 1:
                    alts.append((i, j, "lag", name, x[:, j], sh))
                    alts.append((i, j, "lag", name, x[:, j], -sh))
        if terms[i].effect.lof_constant_height:
            alts.append((i, j, "pose", "q", None, 0))
        alts.append((i, j, "drift", "time", None, 0))
    if not alts:
        return {}
    threshold = SCORE_MIN + math.log(len(alts))
    out: dict[int, list[LackOfFit]] = {}
    sgn_all = np.tanh(data.dq / STEP_VEL)
    ne_r: dict[int, float] = {}  # each joint's residual's effective sample size, computed once
    for i, j, alt, name, x, sh in alts:
        r = residual[idx, j]
        cj = contributions[i][idx, j]
        p = r + cj
        if alt == "pose":
            s = sgn_all[idx, j][:, None]
            X = np.column_stack([cj, s * _indicators(data.q[idx, j], N_POSE),
                                 s * _indicators(ctx.ev.predicted[idx, j], N_POSE)])
            detail = ""
        elif alt == "drift":
            u = 2.0 * (t - t[0]) / max(float(t[-1] - t[0]), 1e-9) - 1.0
            X = np.column_stack([cj, cj * u, cj * 0.5 * (3 * u ** 2 - 1)])
            # the coefficient's relative change from the start to the end of the log, for the description
            beta = np.linalg.lstsq(X, p, rcond=None)[0]
            ends = [beta[0] + beta[1] * e + beta[2] for e in (-1.0, 1.0)]
            ratio = ends[1] / ends[0] if abs(ends[0]) > 1e-12 else 1.0
            detail = f"x{ratio:.2g} from start to end" if abs(ends[0]) > 1e-12 else ""
        else:
            xs = np.roll(x, sh)[idx] if sh else x[idx]
            if sh > 0:
                xs[: sh // step + 1] = x[0]
            elif sh < 0:
                xs[-(-sh // step + 1):] = x[-1]
            X = np.column_stack([cj, _indicators(xs, N_BINS)])
            detail = f"{1e3 * sh / data.settings.rate:+.0f} ms" if sh else ""
        pred = _cv_lin(p, X, fold, len(np.unique(fold)))
        mse0 = float(np.mean(r ** 2))
        mse1 = float(np.mean((p - pred) ** 2))
        if j not in ne_r:
            ne_r[j] = float(n_eff(r))
        ne = max(ne_r[j], float(n_eff(p - pred)), 2.0)
        dk = X.shape[1] - 1
        score = ne * math.log(max(mse0, 1e-30) / max(mse1, 1e-30)) - dk * math.log(ne)
        removed = math.sqrt(max(mse0 - mse1, 0.0))
        # a coefficient that changes by a large factor within one log is qualitatively wrong even when the RMS it
        # leaves is small (the law's contribution itself may be small): a lower size bound then, with the same evidence
        large_drift = (alt == "drift" and removed >= DRIFT_PRACTICAL * noise[j]
                       and (ratio <= 0 or abs(math.log(ratio)) >= math.log(DRIFT_RATIO)))
        if score > threshold and (removed >= PRACTICAL * noise[j] or large_drift):
            out.setdefault(i, []).append(LackOfFit(terms[i].effect.name, j, alt, name, removed, score, threshold,
                                                   detail))
    # per (effect, joint): keep the strongest alternative first
    for i in out:
        out[i].sort(key=lambda f: (f.joint, -f.removed_rms))
    return out


def describe(effect: str, fails: list[LackOfFit], noise: np.ndarray) -> str:
    """One sentence: which effect is only an approximation, on which joints, and what shape remains."""
    parts = []
    for j in sorted({f.joint for f in fails}):
        f = max((f for f in fails if f.joint == j), key=lambda f: f.removed_rms)
        what = WHAT[f.alternative].format(d=f.driver, lag=f.detail)
        parts.append(f"joint {j}: {what} ({f.removed_rms:.3g} Nm beyond the law, noise {noise[j]:.3g} Nm)")
    return (f"{effect} is only the closest library effect (lack of fit): the residual along its own variable follows "
            + "; ".join(parts) + ".")


def mark_lack_of_fit(ctx: Context, eng: Engine, chosen: list[Term], cur: SetFit, residual: np.ndarray,
                 noise: np.ndarray, folds: int, selection: list[Selected], unexplained: Any) -> None:
    """Mark the selected effects whose law does not capture the shape of their own driving variables (see
    :mod:`~franka_vs_gym.validation.lackfit`): the name is kept as the closest library effect, ``explained`` is
    false and the description says what remains."""
    keep = [i for i, t in enumerate(chosen) if not t.effect.name.endswith("_after")]  # a model change: not a law
    contribs = eng.contributions(cur)
    fails = test_lack_of_fit(ctx, [chosen[i] for i in keep], [contribs[i] for i in keep], residual, noise, folds)
    if not fails:
        return
    if unexplained.explained:
        unexplained.text = [s for s in unexplained.text if not s.startswith(("The residual is at the noise",
                                                                             "No structure left"))]
    unexplained.explained = False
    for i, fl in sorted(fails.items()):
        selection[i].lack_of_fit = fl
        unexplained.text.append(describe(selection[i].effect, fl, noise))
        for f in fl:
            unexplained.findings.append(Finding(f.joint, "lack_of_fit", f.removed_rms, f.score,
                                                f"{f.effect}: {f.alternative} of {f.driver} {f.detail}".strip()))


__all__ = ["LackOfFit", "describe", "mark_lack_of_fit", "test_lack_of_fit"]
