"""Diagnose which physical effect a model lacks, and fit effects.

Method (all on the inverse-dynamics residual ``r = tau_J - tau_model`` of the baseline model):

1. **Held-out error.** The log is cut into ``folds`` contiguous blocks (5 by default). Each candidate effect is fitted
   on all blocks but one and predicts the held-out block; the held-out residuals of all blocks give the effect's
   held-out mean squared error per joint, ``MSE1_j``, to compare with the baseline's ``MSE0_j``. Contiguous blocks
   keep the strongly correlated neighbouring 1 kHz samples on the same side of the split.
2. **Information criterion with an effective sample size.** Samples at 1 kHz are not independent. For each joint the
   integrated autocorrelation time ``tau_int = 1 + 2 sum_k rho_k`` of the held-out residual (summed while rho_k > 0)
   gives ``N_eff = N / tau_int``. The score of an effect is a BIC-like evidence
   ``sum_j N_eff_j ln(MSE0_j / MSE1_j) - k ln(N_eff)`` (k its number of parameters); per-joint effects are scored
   and kept joint by joint (a joint is kept when its own score exceeds ``JOINT_SCORE_MIN``).
3. **Significance.** An effect is *significant* when its score exceeds ``SCORE_MIN`` **and** it removes an error of
   practical size: on at least one joint, the RMS of what it removes, ``sqrt(MSE0 - MSE1)``, is at least
   ``PRACTICAL`` times the measurement noise floor. A residual already at the noise floor therefore yields no
   significant effect: the verdict is ``none``.
4. **Plausibility.** Fitted parameters are checked for sign and magnitude (negative friction, a 5 kg payload, a 40
   degree tilt, a negative delay are rejected); implausible joints are dropped, an implausible effect is ranked
   after the plausible ones and cannot be the verdict.
5. **Collinear groups.** Two significant effects whose fitted contributions are strongly correlated
   (|cos| > ``COLLINEAR``) are also fitted together (alternating least squares); the group enters the ranking when it
   beats its best member by ``SCORE_MIN`` and removes an extra error of at least ``GROUP_PRACTICAL`` times the
   noise floor on some joint.
6. **Selection.** Starting from the baseline, significant effects are added greedily while each one is significant
   with respect to the model that already has the previous ones, and stopping when the held-out RMSE of every joint
   is within ``FLOOR_STOP`` of the noise floor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.validation.compare import as_processed, baseline_config, progress, rmse
from franka_vs_gym.validation.effects import COMMAND_DELAY, LIBRARY, Context, Effect, Fit, get_effect
from franka_vs_gym.validation.evaluate import evaluate
from franka_vs_gym.validation.logs import MeasurementLog
from franka_vs_gym.validation.signals import CleanSettings, ProcessedLog

SCORE_MIN = 10.0
JOINT_SCORE_MIN = 2.0
PRACTICAL = 0.1
GROUP_PRACTICAL = 0.25
COLLINEAR = 0.8
FLOOR_STOP = 1.05
FOLDS = 5


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
    m = 1 << int(np.ceil(np.log2(n + lag + 1)))
    f = np.fft.rfft(x, m, axis=0)
    ac = np.fft.irfft(f.real ** 2 + f.imag ** 2, m, axis=0)[: lag + 1] / np.maximum(var, 1e-300)
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


@dataclass
class Candidate:
    """One ranking entry: an effect (or a group "a+b") with its joints, parameters, held-out RMSE per joint (Nm),
    score, and flags."""

    effect: str
    members: list[str]
    joints: list[int]
    params: dict[str, Any]
    rmse_tau_after: np.ndarray
    score: float
    significant: bool
    plausible: bool
    problems: list[str] = field(default_factory=list)
    removed_rms: np.ndarray = field(default_factory=lambda: np.zeros(7))
    joint_scores: np.ndarray = field(default_factory=lambda: np.zeros(7))
    fits: list[Fit] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d = {"effect": self.effect, "joints": list(map(int, self.joints)), "params": self.params,
             "rmse_tau_after": np.round(self.rmse_tau_after, 4).tolist(), "score": round(float(self.score), 2),
             "significant": bool(self.significant), "plausible": bool(self.plausible),
             "removed_rms": np.round(self.removed_rms, 4).tolist()}
        if len(self.members) > 1:
            d["group"] = list(self.members)
        if self.problems:
            d["problems"] = self.problems
        return d


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`: baseline RMSE (7,), total, noise floor (7,), ranking (best first), verdict,
    selected effects (greedy, stopping at the noise floor) and the baseline configuration."""

    rmse_tau: np.ndarray
    rmse_tau_total: float
    noise_floor: np.ndarray
    ranking: list[Candidate]
    verdict: str
    selected: list[str]
    config: ModelConfig
    context: Context

    def to_dict(self) -> dict[str, Any]:
        return {"rmse_tau": np.round(self.rmse_tau, 4).tolist(), "rmse_tau_total": round(float(self.rmse_tau_total), 4),
                "noise_floor": np.round(self.noise_floor, 4).tolist(),
                "ranking": [c.to_dict() for c in self.ranking], "verdict": self.verdict,
                "selected": list(self.selected)}


def _folds(n: int, k: int) -> list[np.ndarray]:
    edges = np.linspace(0, n, k + 1).astype(int)
    return [np.arange(edges[i], edges[i + 1]) for i in range(k)]


def _fit_set(ctx: Context, members: list[tuple[Effect, list[int] | None]], y: np.ndarray, idx: np.ndarray,
             rounds: int = 3) -> tuple[list[Fit], np.ndarray]:
    """Fit several effects together on samples idx by alternating least squares; returns fits and the total
    contribution (N, 7)."""
    k = len(members)
    contrib = [np.zeros_like(y) for _ in range(k)]
    fits: list[Fit] = [None] * k  # type: ignore[list-item]
    for _ in range(1 if k == 1 else rounds):
        for i, (e, joints) in enumerate(members):
            others = sum((contrib[m] for m in range(k) if m != i), np.zeros_like(y))
            f = e.fit(ctx, y - others, idx)
            if joints is not None:
                f.joints = list(joints)
            fits[i] = f
            contrib[i] = e.contribution(ctx, f)
    return fits, sum(contrib, np.zeros_like(y))


def _cross_validate(ctx: Context, members, y: np.ndarray, folds: list[np.ndarray]) -> np.ndarray:
    out = np.empty_like(y)
    n = ctx.n
    for blk in folds:
        mask = np.ones(n, dtype=bool)
        mask[blk] = False
        _, c = _fit_set(ctx, members, y, np.nonzero(mask)[0])
        out[blk] = y[blk] - c[blk]
    return out


def _score(ctx: Context, members, y: np.ndarray, folds, noise: np.ndarray, mse0: np.ndarray | None = None):
    """Held-out evaluation of a set of effects on target y: returns dict with mse1, neff, joint scores, etc."""
    r_cv = _cross_validate(ctx, members, y, folds)
    mse0 = np.mean(y ** 2, axis=0) if mse0 is None else mse0
    mse1 = np.mean(r_cv ** 2, axis=0)
    neff = n_eff(r_cv)
    gain = neff * np.log(mse0 / np.maximum(mse1, 1e-30))
    removed = np.sqrt(np.maximum(mse0 - mse1, 0.0))
    return {"mse0": mse0, "mse1": mse1, "neff": neff, "gain": gain, "removed": removed, "r_cv": r_cv}


def _evaluate_candidate(ctx: Context, members: list[Effect], y: np.ndarray, folds, noise: np.ndarray,
                        joints_fixed: list[list[int] | None] | None = None) -> Candidate:
    spec = [(e, None if joints_fixed is None else joints_fixed[i]) for i, e in enumerate(members)]
    s = _score(ctx, spec, y, folds, noise)
    mse0, mse1, neff, gain, removed = s["mse0"], s["mse1"], s["neff"], s["gain"], s["removed"]
    # final fit on all samples
    fits, _ = _fit_set(ctx, spec, y, np.arange(ctx.n))
    problems: list[str] = []
    joint_bad: set[int] = set()
    for e, f in zip(members, fits, strict=True):
        for j, msg in e.problems(ctx, f).items():
            if j < 0:
                problems.append(f"{e.name}: {msg}")
            else:
                joint_bad.add(j)
    single = len(members) == 1
    e0 = members[0]
    if single and e0.per_joint:
        js = gain - e0.n_params * np.log(neff)
        keep = [j for j in range(7) if js[j] > JOINT_SCORE_MIN and j not in joint_bad
                and removed[j] >= PRACTICAL * noise[j]]
        score = float(js[keep].sum()) if keep else float(min(js.max(), 0.0))
        after = np.sqrt(mse0.copy())
        after[keep] = np.sqrt(mse1[keep])
        for f in fits:
            f.joints = keep
        joints = keep
        plausible = not problems and bool(keep or not joint_bad)
        practical = bool(keep)
    else:
        k = sum(e.n_params * (7 if e.per_joint else 1) for e in members)
        js = gain.copy()
        score = float(gain.sum() - k * np.log(max(neff.mean(), 2.0)))
        joints = [j for j in range(7) if removed[j] >= PRACTICAL * noise[j] and gain[j] > 0]
        after = np.sqrt(mse1)
        per_joint_problems = [f"joint {j}: implausible" for j in sorted(joint_bad)]
        problems += per_joint_problems
        plausible = not problems
        practical = bool(joints)
    params: dict[str, Any] = {}
    for e, f in zip(members, fits, strict=True):
        pub = e.public(f)
        if len(members) > 1:
            params[e.name] = pub
        else:
            params.update(pub)
    if single and e0.name == "gravity_tilt":
        params["tilt_deg"] = round(e0.tilt_deg(ctx, fits[0]), 4)
    significant = bool(score > SCORE_MIN and practical)
    return Candidate("+".join(e.name for e in members), [e.name for e in members], joints, params, after, score,
                     significant, plausible, problems, removed, js, fits)


def _is_command(c: Candidate) -> bool:
    return c.params.get("channel") == "command"


def _pick_delay_channel(ctx: Context, measured: Candidate, fl, noise: np.ndarray) -> Candidate:
    """The delay seen on the inverse-dynamics residual (the measured torque lags the motion) or, when that is not
    significant, on the command channel (the measured torque lags the logged command)."""
    if measured.significant and measured.plausible:
        return measured
    cmd = _evaluate_candidate(ctx, [COMMAND_DELAY], ctx.cmd_residual, fl, noise)
    if not (cmd.significant and cmd.plausible):
        return measured
    # a command delay leaves the inverse-dynamics prediction unchanged: report both residuals
    cmd.params["command_rmse_before"] = np.round(rmse(ctx.cmd_residual), 4).tolist()
    cmd.params["command_rmse_after"] = np.round(cmd.rmse_tau_after, 4).tolist()
    cmd.rmse_tau_after = rmse(ctx.residual)
    return cmd


def _order(c: Candidate) -> tuple:
    return (not (c.significant and c.plausible), not c.plausible, -c.score)


def diagnose(log: MeasurementLog | ProcessedLog | str, model: Any = None, *, rigid_body: bool = False,
             effects: list[str] | None = None, settings: CleanSettings | None = None, folds: int = FOLDS,
             select: bool = True, verbose: bool = False) -> Diagnosis:
    """Rank the candidate effects the model ``model`` (default: the log's baseline) lacks on ``log``."""
    progress("cleaning the log", verbose)
    data = as_processed(log, settings)
    cfg = baseline_config(data.log, model, rigid_body)
    progress(f"evaluating the baseline model and regressors on {data.n} samples", verbose)
    ctx = Context(data, cfg)
    y = ctx.residual
    noise = data.noise
    fl = _folds(ctx.n, folds)
    names = list(LIBRARY) if effects is None else [get_effect(n).name for n in effects]
    ranking = []
    for i, name in enumerate(names):
        progress(f"[{i + 1}/{len(names)}] held-out fit of {name}", verbose)
        cand = _evaluate_candidate(ctx, [LIBRARY[name]], y, fl, noise)
        if name == "delay" and ctx.cmd_residual is not None:
            cand = _pick_delay_channel(ctx, cand, fl, noise)
        ranking.append(cand)
    # collinear groups among significant effects (on the inverse-dynamics residual)
    sig = [c for c in ranking if c.significant and not _is_command(c)]
    contribs = {c.effect: LIBRARY[c.effect].contribution(ctx, c.fits[0]) for c in sig}
    groups = []
    for a in range(len(sig)):
        for b in range(a + 1, len(sig)):
            ca, cb = contribs[sig[a].effect], contribs[sig[b].effect]
            den = math.sqrt(float(np.einsum("ij,ij->", ca, ca)) * float(np.einsum("ij,ij->", cb, cb)))
            if den > 0 and abs(float(np.einsum("ij,ij->", ca, cb))) / den > COLLINEAR:
                progress(f"collinear pair: fitting {sig[a].effect} and {sig[b].effect} together", verbose)
                g = _evaluate_candidate(ctx, [LIBRARY[sig[a].effect], LIBRARY[sig[b].effect]], y, fl, noise)
                best = sig[a] if sig[a].score >= sig[b].score else sig[b]
                # the group must beat its best member statistically AND by an error of practical size
                extra = np.sqrt(np.maximum(best.rmse_tau_after ** 2 - g.rmse_tau_after ** 2, 0.0))
                if g.score > best.score + SCORE_MIN and g.significant and np.any(extra >= GROUP_PRACTICAL * noise):
                    groups.append(g)
    ranking += groups
    ranking.sort(key=_order)
    top = ranking[0] if ranking else None
    verdict = top.effect if top is not None and top.significant and top.plausible else "none"
    selected: list[str] = []
    if select and verdict != "none":
        selected = _select(ctx, ranking, y, fl, noise, verbose)
    base_rmse = rmse(y)
    return Diagnosis(base_rmse, float(np.sqrt(np.mean(y ** 2))), noise.copy(), ranking, verdict, selected, cfg, ctx)


def _select(ctx: Context, ranking: list[Candidate], y: np.ndarray, fl, noise: np.ndarray, verbose: bool,
            max_effects: int = 4) -> list[str]:
    """Greedy forward selection among the significant plausible singles, stopping at the noise floor."""
    pool = [c for c in ranking if c.significant and c.plausible and len(c.members) == 1 and not _is_command(c)]
    command = [c.effect for c in ranking if c.significant and c.plausible and _is_command(c)]
    chosen: list[Candidate] = []
    mse_cur = np.mean(y ** 2, axis=0)
    while pool and len(chosen) < max_effects:
        if np.all(np.sqrt(mse_cur) <= FLOOR_STOP * noise):
            break
        best, best_s = None, None
        for c in pool[:5]:
            members = [(LIBRARY[m.effect], m.joints if LIBRARY[m.effect].per_joint else None) for m in chosen + [c]]
            progress(f"selection: trying {'+'.join(m.effect for m in chosen + [c])}", verbose)
            s = _score(ctx, members, y, fl, noise, mse0=mse_cur)
            k = LIBRARY[c.effect].n_params * (len(c.joints) if LIBRARY[c.effect].per_joint else 1)
            val = float(s["gain"].sum() - k * np.log(max(s["neff"].mean(), 2.0)))
            practical = bool(np.any(s["removed"] >= PRACTICAL * noise))
            if practical and val > SCORE_MIN and (best_s is None or val > best_s[0]):
                best, best_s = c, (val, s["mse1"])
        if best is None:
            break
        chosen.append(best)
        mse_cur = best_s[1]
        pool.remove(best)
    # a command delay does not interact with the inverse-dynamics effects
    return [c.effect for c in chosen] + command


@dataclass
class FitResult:
    """Fitted effects applied to a model: the configuration before and after, the fits, and the per-joint RMSE
    (Nm) of the inverse-dynamics residual before and after (the after value re-computed with the full model built
    from the new configuration, not from the linearised fit)."""

    before: ModelConfig
    after: ModelConfig
    effects: list[str]
    fits: list[Fit]
    params: dict[str, Any]
    rmse_before: np.ndarray
    rmse_after: np.ndarray
    noise_floor: np.ndarray
    data: ProcessedLog
    residual_before: np.ndarray
    residual_after: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        return {"effects": self.effects, "params": self.params,
                "rmse_tau_before": np.round(self.rmse_before, 4).tolist(),
                "rmse_tau_after": np.round(self.rmse_after, 4).tolist(),
                "rmse_tau_total_before": round(float(rmse(self.rmse_before)), 4),
                "rmse_tau_total_after": round(float(rmse(self.rmse_after)), 4),
                "noise_floor": np.round(self.noise_floor, 4).tolist()}


def fit_effects(log: MeasurementLog | ProcessedLog | str, effects: list[str], model: Any = None, *,
                rigid_body: bool = False, settings: CleanSettings | None = None, verbose: bool = False) -> FitResult:
    """Fit ``effects`` (names, or ["auto"] for the diagnosis' selection) on the whole log, apply them to the model
    configuration (model and plant), and re-compare."""
    data = as_processed(log, settings)
    cfg = baseline_config(data.log, model, rigid_body)
    if [e.strip() for e in effects] == ["auto"]:
        d = diagnose(data, cfg, verbose=verbose)
        names = d.selected or ([] if d.verdict == "none" else d.ranking[0].members)
        ctx = d.context
        joints_of = {c.effect: c.joints for c in d.ranking if len(c.members) == 1}
        progress(f"auto: selected {names or 'nothing (verdict none)'}", verbose)
    else:
        names = []
        for e in (part for item in effects for part in item.split("+")):
            n = get_effect(e).name
            if n in names:
                raise ValueError(f"effect {n!r} given twice")
            names.append(n)
        progress(f"evaluating the baseline model and regressors on {data.n} samples", verbose)
        ctx = Context(data, cfg)
        joints_of = {}
    y = ctx.residual
    noise = data.noise
    fl = _folds(ctx.n, FOLDS)
    command_fit = None
    if "delay" in names and ctx.cmd_residual is not None:
        progress("delay: choosing the channel (measured torque vs motion, or vs command)", verbose)
        c = _pick_delay_channel(ctx, _evaluate_candidate(ctx, [LIBRARY["delay"]], y, fl, noise), fl, noise)
        if _is_command(c):
            command_fit = COMMAND_DELAY.fit(ctx, ctx.cmd_residual, np.arange(ctx.n))
            names = [n for n in names if n != "delay"]
    members = [LIBRARY[n] for n in names]
    # joints of per-joint effects: those where the held-out fit of the whole set helps and is plausible
    spec = []
    for e in members:
        if e.per_joint and e.name not in joints_of and names:
            progress(f"held-out joint selection for {e.name}", verbose)
            c = _evaluate_candidate(ctx, [e], y, fl, noise)
            js = c.joints if c.joints else [j for j in range(7) if c.joint_scores[j] > 0]
            joints_of[e.name] = js
        spec.append((e, joints_of.get(e.name) if e.per_joint else None))
    progress(f"fitting {names} on all samples", verbose)
    fits, _ = _fit_set(ctx, spec, y, np.arange(ctx.n)) if names else ([], None)
    # alternating fits with the non-linear refinement (sigmoid shape, exact delay) inside, each effect fitted to
    # the residual left by the others
    everything = np.arange(ctx.n)
    for _ in range(3 if len(spec) > 1 else 1):
        for i, (e, joints) in enumerate(spec):
            others = sum((spec[m][0].contribution(ctx, fits[m]) for m in range(len(spec)) if m != i),
                         np.zeros_like(y))
            f = e.fit(ctx, y - others, everything)
            if joints is not None:
                f.joints = list(joints)
            f = e.refine(ctx, y - others, f)
            if joints is not None:
                f.joints = list(joints)
            fits[i] = f
    new = cfg
    for e, f in zip(members, fits, strict=True):
        new = e.apply(new, f)
    if command_fit is not None:
        new = COMMAND_DELAY.apply(new, command_fit)
        members, fits, names = members + [COMMAND_DELAY], fits + [command_fit], names + ["delay"]
    new = new.copy(notes={**new.notes, "calibrated_on": str(data.log.source), "effects": names})
    progress("re-comparing with the calibrated model", verbose)
    ev = evaluate(new, data)
    r_after = data.tau - ev.predicted
    params = {e.name: {**e.public(f), "joints": list(map(int, f.joints))} for e, f in zip(members, fits, strict=True)}
    return FitResult(cfg, new, names, fits, params, rmse(y), rmse(r_after), noise.copy(), data, y, r_after)


__all__ = ["Candidate", "Diagnosis", "FitResult", "diagnose", "fit_effects", "n_eff", "SCORE_MIN", "PRACTICAL"]
