"""The workbench's result types: what ``compare``, ``diagnose`` and ``fit`` return, and what every output, report
and the browser app reads.

This module is the seam between the estimator (which computes these) and the readers (the CLI's JSON, the static
reports, the app): readers take these objects as they are and compute nothing again. Arrays are per joint (7,) in Nm
(torque) or rad (position) unless said; ``to_dict`` gives the JSON form every command writes.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.validation.effects import Context, Fit
from franka_vs_gym.validation.evaluate import ModelEvaluation
from franka_vs_gym.validation.selection import Term
from franka_vs_gym.validation.signals import ProcessedLog

__all__ = ["rmse", "ReplayResult", "CompareResult", "Candidate", "Selected", "Ambiguity", "ModelChange",
           "Diagnosis", "FitResult"]


def rmse(x: np.ndarray, axis: int = 0) -> np.ndarray:
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=axis))


@dataclass
class ReplayResult:
    """Simulation replay: mode ("controller", "torque" or "tracking"), RMSE_q (7,) rad, RMSE_tau (7,) Nm and the
    simulated q, tau_J (N, 7) (NaN where not replayed: before the start of a controller replay, after a
    divergence)."""

    mode: str
    rmse_q: np.ndarray
    rmse_tau: np.ndarray
    q: np.ndarray
    tau: np.ndarray
    diverged: str | None = None
    #: how this replay stopped early (mode, time, joint, reason), or None when it ran to the end of the log
    stop: dict[str, Any] | None = None
    #: the replays tried before this one that could not run (each a ``stop`` record); this one is the fallback
    fallback_from: list[dict[str, Any]] = field(default_factory=list)
    #: the plant's step (s): at most 1 ms, a whole number of steps per log sample (None: not recorded)
    plant_dt: float | None = None

    def to_dict(self) -> dict[str, Any]:
        def clean_list(a: np.ndarray, nd: int) -> list:
            return [None if not np.isfinite(x) else round(float(x), nd) for x in a]

        tot_q, tot_tau = float(rmse(self.rmse_q)), float(rmse(self.rmse_tau))
        return {"mode": self.mode, "rmse_q": clean_list(self.rmse_q, 6), "rmse_tau": clean_list(self.rmse_tau, 4),
                "rmse_q_total": tot_q if np.isfinite(tot_q) else None,
                "rmse_tau_total": tot_tau if np.isfinite(tot_tau) else None, "diverged": self.diverged,
                "stop": self.stop, "fallback_from": self.fallback_from, "status": self.status(),
                "plant_dt_s": None if self.plant_dt is None else round(float(self.plant_dt), 7)}

    def status(self) -> str:
        """One line: what was replayed, and which replays could not run and why."""
        out = [f"{s['mode']} replay stopped at t = {s['time_s']:.3f} s"
               + (f" (joint {s['joint']})" if s.get("joint") is not None else "") + f": {s['reason']}"
               for s in self.fallback_from]
        if out:
            out.append(f"fell back to the {self.mode} replay")
        if self.stop is not None:
            s = self.stop
            out.append(f"{s['mode']} replay stopped at t = {s['time_s']:.3f} s"
                       + (f" (joint {s['joint']})" if s.get("joint") is not None else "") + f": {s['reason']}; "
                       "its RMSE covers the samples before")
        return "; ".join(out) if out else f"{self.mode} replay ran to the end of the log"


@dataclass
class CompareResult:
    """Inverse-dynamics comparison of one model with one log (arrays (7,) per joint unless said).

    residual (N, 7) Nm = tau_J - tau_model; rmse_tau, mean_tau (bias), max_abs_tau per joint; rmse_tau_total the
    RMS over all joints and samples; noise_floor the estimated measurement noise; concentration: rows of the table
    of where the error concentrates; replay: a ReplayResult or None.
    """

    config: ModelConfig
    data: ProcessedLog
    evaluation: ModelEvaluation
    residual: np.ndarray
    rmse_tau: np.ndarray
    rmse_tau_total: float
    mean_tau: np.ndarray
    max_abs_tau: np.ndarray
    noise_floor: np.ndarray
    concentration: list[dict[str, Any]] = field(default_factory=list)
    replay: ReplayResult | None = None

    def to_dict(self) -> dict[str, Any]:
        return {
            "rmse_tau": self.rmse_tau.round(4).tolist(), "rmse_tau_total": round(float(self.rmse_tau_total), 4),
            "noise_floor": self.noise_floor.round(4).tolist(), "mean_tau": self.mean_tau.round(4).tolist(),
            "max_abs_tau": self.max_abs_tau.round(4).tolist(), "samples": int(self.data.n),
            "duration_s": round(float(self.data.time[-1] - self.data.time[0]), 4),
            "cleaning": self.data.report.to_dict(), "concentration": self.concentration,
            "replay": None if self.replay is None else self.replay.to_dict(),
            "assumptions": self.assumptions(),
        }

    def assumptions(self) -> dict[str, Any]:
        """Tool, gravity, rate and cleaning this comparison assumed (see ``structure.assumptions_of``)."""
        from franka_vs_gym.validation.structure import assumptions_of

        return assumptions_of(self.data, self.config)


@dataclass
class Candidate:
    """One ranking entry: an effect (or a group "a+b") with its joints, parameters, held-out RMSE per joint (Nm),
    score, and flags. ``problems`` says why an effect is not plausible (sign, magnitude, physical range)."""

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
    terms: list[Term] = field(default_factory=list)
    mse_cv: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        return self.significant and self.plausible

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
class Selected:
    """One effect of the selected set: its joints, parameters (fitted jointly with the rest of the set), the error it
    removes per joint in the context of the others (``contribution``, Nm: sqrt(MSE without it - MSE with it), held
    out) and its score in that context."""

    effect: str
    joints: list[int]
    params: dict[str, Any]
    contribution: np.ndarray
    score: float
    channel: str = "inverse_dynamics"
    lack_of_fit: list[Any] = field(default_factory=list)  # failed lack-of-fit tests (lackfit.LackOfFit)
    # 95 % intervals (same structure as params, [low, high] or None where not identifiable), strongly correlated
    # parameter pairs and unidentifiable combinations in words (validation.uncertainty)
    params_ci95: dict[str, Any] = field(default_factory=dict)
    correlations: list[dict[str, Any]] = field(default_factory=list)
    unidentifiable: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d = {"effect": self.effect, "joints": list(map(int, self.joints)), "params": self.params,
             "params_ci95": self.params_ci95, "correlations": self.correlations,
             "unidentifiable": self.unidentifiable,
             "contribution": np.round(self.contribution, 4).tolist(), "score": round(float(self.score), 2),
             "channel": self.channel}
        if self.lack_of_fit:
            d["lack_of_fit"] = {"status": "closest library effect, lack of fit",
                                "joints": sorted({f.joint for f in self.lack_of_fit}),
                                "tests": [f.to_dict() for f in self.lack_of_fit]}
        return d


@dataclass
class Ambiguity:
    """Explanations the log cannot tell apart: ``candidates`` (effect names, the selected one first) on ``joints``,
    their held-out ``evidence`` (name -> score of the selected set with that candidate in place; within
    ``AMBIGUOUS`` of each other), and ``separate_by``: in words, the motion that would separate them."""

    candidates: list[str]
    joints: list[int]
    evidence: dict[str, float]
    separate_by: str

    def to_dict(self) -> dict[str, Any]:
        return {"candidates": list(self.candidates), "joints": list(map(int, self.joints)),
                "evidence": {k: round(float(v), 2) for k, v in self.evidence.items()},
                "separate_by": self.separate_by}

    def text(self) -> str:
        ev = ", ".join(f"{k} {v:.1f}" for k, v in self.evidence.items())
        return (f"ambiguous on joint{'s' if len(self.joints) != 1 else ''} {', '.join(map(str, self.joints))}: "
                f"{' or '.join(self.candidates)} explain the log equally well (held-out evidence {ev}); "
                f"to separate them record {self.separate_by}")


@dataclass
class ModelChange:
    """The model changes during the log at ``t`` (s from the start of the processed log): ``what`` in words, the
    parameters ``before`` and ``after`` (e.g. a payload's mass and centre of mass)."""

    t: float
    what: str
    before: dict[str, Any]
    after: dict[str, Any]

    def to_dict(self) -> dict[str, Any]:
        return {"t": round(float(self.t), 3), "what": self.what, "before": self.before, "after": self.after}

    def text(self) -> str:
        return f"the model changes at t = {self.t:.2f} s: {self.what}"


@dataclass
class Diagnosis:
    """Result of :func:`diagnose`: baseline RMSE (7,) Nm, total, noise floor (7,), ranking (each effect alone, best
    first), verdict (the strongest selected effect or "none"), the selected set (``selection``; ``selected`` its
    names), the held-out RMSE of the selected set (7,), the structure test of what remains (``unexplained``), the
    stated assumptions, notes (rejections and warnings), the baseline configuration and the context."""

    rmse_tau: np.ndarray
    rmse_tau_total: float
    noise_floor: np.ndarray
    ranking: list[Candidate]
    verdict: str
    selection: list[Selected]
    config: ModelConfig
    context: Context
    rmse_tau_selected: np.ndarray | None = None
    unexplained: Any = None
    assumptions: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    residual: np.ndarray | None = None
    data: ProcessedLog | None = None  # the whole processed log (the context may hold a decimated copy)
    ambiguous: list[Ambiguity] = field(default_factory=list)
    changes: list[ModelChange] = field(default_factory=list)
    # each selected effect's torque (N, 7) Nm on the analysed samples (context.data.time), fitted with the set
    contributions: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def selected(self) -> list[str]:
        return [s.effect for s in self.selection]

    @property
    def explained(self) -> bool:
        return self.unexplained is None or self.unexplained.explained

    def to_dict(self) -> dict[str, Any]:
        d = {"rmse_tau": np.round(self.rmse_tau, 4).tolist(), "rmse_tau_total": round(float(self.rmse_tau_total), 4),
             "noise_floor": np.round(self.noise_floor, 4).tolist(),
             "ranking": [c.to_dict() for c in self.ranking], "verdict": self.verdict,
             "selected": [s.to_dict() for s in self.selection]}
        if self.rmse_tau_selected is not None:
            d["rmse_tau_selected"] = np.round(self.rmse_tau_selected, 4).tolist()
        if self.unexplained is not None:
            d["explained"] = bool(self.unexplained.explained)
            d["unexplained"] = self.unexplained.to_dict()
        d["ambiguous"] = [list(a.candidates) for a in self.ambiguous]
        d["ambiguity"] = [a.to_dict() for a in self.ambiguous]
        d["changes"] = [c.to_dict() for c in self.changes]
        d["assumptions"] = self.assumptions
        d["notes"] = list(self.notes)
        return d


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
    holdout: dict[str, Any] | None = None
    assumptions: dict[str, Any] = field(default_factory=dict)
    #: effect -> what was constrained, left out or not applied, and why (one line each)
    notes: dict[str, str] = field(default_factory=dict)
    # 95 % intervals per effect (same structure as params), correlated pairs, unidentifiable combinations
    params_ci95: dict[str, Any] = field(default_factory=dict)
    correlations: list[dict[str, Any]] = field(default_factory=list)
    unidentifiable: list[str] = field(default_factory=list)
    # each fitted effect's torque (N, 7) Nm on contribution_time (the fitting samples; the log may be decimated)
    contributions: dict[str, np.ndarray] = field(default_factory=dict)
    contribution_time: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"effects": self.effects, "params": self.params, "notes": self.notes, "params_ci95": self.params_ci95,
                "correlations": self.correlations, "unidentifiable": self.unidentifiable,
                "rmse_tau_before": np.round(self.rmse_before, 4).tolist(),
                "rmse_tau_after": np.round(self.rmse_after, 4).tolist(),
                "rmse_tau_total_before": round(float(rmse(self.rmse_before)), 4),
                "rmse_tau_total_after": round(float(rmse(self.rmse_after)), 4),
                "noise_floor": np.round(self.noise_floor, 4).tolist(), "holdout": self.holdout,
                "assumptions": self.assumptions}
