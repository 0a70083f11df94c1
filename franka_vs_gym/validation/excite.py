"""Designed excitation: the motion to record next, so that the effects in question are identified with narrow
intervals (or told apart).

The motion is a finite Fourier series per joint (Swevers, Ganseman, Tukel, De Schutter and Van Brussel, IEEE Trans.
Robot. Autom. 13(5) 1997; the form of the Gaz et al. 2019 excitation), between rests at its centre pose::

    q_j(t) = c_j + sum_l a_jl sin(w_l s) + b_jl (cos(w_l s) - 1),   w_l = 2 pi l / T_p,   s = t - rest

repeated over whole periods ``T_p``. Two linear conditions per joint fix ``a_j1`` and ``b_j1`` so that velocity and
acceleration are zero where the motion leaves and joins the rests (``sum_l a_jl w_l = 0``, ``sum_l b_jl w_l^2 = 0``):
the robot starts and ends at rest, with a continuous acceleration.

**Criterion.** The workbench's own regressor: a validation :class:`~franka_vs_gym.validation.effects.Context` is
built from the candidate motion (its q, dq, ddq sampled on one period, plus its rest pose; the robot's model), and
each effect in question gives its columns (:meth:`~franka_vs_gym.validation.effects.Effect.design`, friction laws
and the delay's ``-d tau/dt`` included). With white torque noise ``sigma_j`` per joint (the robot's typical floor,
or the noise of a given log) and an effective sample size ``N_eff = duration x neff_rate`` (samples of a 1 kHz robot
log are correlated through the unmodelled part of the residual; ``neff_rate`` 100 Hz by default, i.e. an integrated
autocorrelation time of 10 ms), the parameters' predicted covariance is ``(neff_rate sum_k dt_k x_k W x_k^T)^-1``
and their 95 % interval half-width ``1.96 sqrt(diag)``. The design maximises ``log det`` of the information matrix
normalised by that of a reference motion (D-optimal: small joint confidence region, and effects whose columns are
collinear are pulled apart, which is what ``--separate`` needs) or its smallest eigenvalue (E-optimal: the
worst-identified direction).

**Limits.** Joint positions within the limits minus ``pos_margin``; velocities, accelerations and jerks within
``fraction`` of the robot's limits (``model.limits()``); the flange at least ``clearance`` above the table top
(z = 0 of the base frame) and the end effector and the wrist (joints 5-7) at least ``clearance / 2``, checked
with the model's kinematics. Every candidate is scaled about its centre pose to the largest size within these
limits (linear in the scale for the joint limits, bisection for the clearance), so the optimiser
(``scipy.optimize.minimize``, L-BFGS-B from the best of 8 random starts, within a wall-time budget) only compares
motions the robot may play; the result is re-checked on a 200 Hz grid of the whole motion.

**Scope.** Non-linear shape parameters (smoothing and Stribeck velocities) are held at nominal values; the model's
sigmoid is designed for through its sensitivities to phi1, phi2, phi3. Self-collision and obstacles other than the
table are not checked.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.validation.excite_information import (
    DESIGN_SAMPLES,
    Columns,
    log_information,
    motion_information,
    predicted_widths,
)
from franka_vs_gym.validation.excite_motion import FourierMotion, Kinematics, Limits, generic_motion, max_scale

NEFF_RATE = 100.0  # Hz: effective independent samples per second of a 1 kHz log (integrated autocorrelation 10 ms)
SEARCH_SAMPLES = 48  # samples of one period while searching (8 Hz for a 6 s period: 10 per period of its top
# harmonic, 0.83 Hz)
PERIOD = 6.0  # s, the nominal period of the Fourier series (f0 about 0.17 Hz; 5 harmonics reach 0.83 Hz)


class _OutOfTime(Exception):
    pass


# ---------------------------------------------------------------------------------------------- design
@dataclass
class Design:
    """An excitation design: the motion, what it was designed for, the predicted 95 % widths of the designed motion
    and of the reference, and the optimiser's record."""

    motion: FourierMotion
    effects: list[str]
    separate: list[list[str]]
    criterion: str
    names: list[str]
    owner: list[str]
    widths: np.ndarray
    widths_reference: np.ndarray
    reference: str
    noise: np.ndarray
    neff_rate: float
    seconds: float
    evaluations: int
    collinearity: dict[str, dict[str, float]] = field(default_factory=dict)
    limits: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> list[dict[str, Any]]:
        """Per effect: the median over its parameters of the width ratio reference / designed."""
        out = []
        for e in self.effects:
            idx = [i for i, o in enumerate(self.owner) if o == e]
            wd, wr = self.widths[idx], self.widths_reference[idx]
            fin = np.isfinite(wd) & np.isfinite(wr) & (wd > 0)
            ratio = float(np.median(wr[fin] / wd[fin])) if fin.any() else float("nan")
            out.append({"effect": e, "parameters": len(idx), "median_width_ratio_reference_over_designed": ratio,
                        "unidentified_reference": int(np.sum(~np.isfinite(wr))),
                        "unidentified_designed": int(np.sum(~np.isfinite(wd)))})
        return out

    def to_dict(self) -> dict[str, Any]:
        def num(x):
            return None if not np.isfinite(x) else float(f"{x:.6g}")

        return {"effects": self.effects, "separate": self.separate, "criterion": self.criterion,
                "noise_model": f"white torque noise {np.round(self.noise, 3).tolist()} Nm per joint, effective sample "
                               f"size duration x {self.neff_rate:g} Hz",
                "reference": self.reference,
                "predicted_ci95_width": {n: {"designed": num(a), "reference": num(b)}
                                         for n, a, b in zip(self.names, self.widths, self.widths_reference,
                                                            strict=True)},
                "summary": self.summary(), "collinearity": self.collinearity, "limits": self.limits,
                "motion": self.motion.to_dict(), "design_seconds": round(self.seconds, 2),
                "criterion_evaluations": self.evaluations}


def _collinearity(cols: Columns, groups: list[list[str]]) -> dict[str, float]:
    """For each pair of effects to separate: the cosine of the smallest principal angle between their
    (noise-weighted) column spaces (1: indistinguishable, 0: orthogonal)."""
    from scipy.linalg import subspace_angles

    out = {}
    A = cols.A.reshape(-1, cols.A.shape[2])
    for g in groups:
        for i in range(len(g)):
            for k in range(i + 1, len(g)):
                ia = [p for p, o in enumerate(cols.owner) if o == g[i]]
                ib = [p for p, o in enumerate(cols.owner) if o == g[k]]
                ang = subspace_angles(A[:, ia], A[:, ib])
                out[f"{g[i]}|{g[k]}"] = float(np.cos(ang.min()))
    return out


def design_excitation(effects: list[str], *, separate: list[list[str]] | None = None, duration: float = 30.0,
                      config: ModelConfig | None = None, criterion: str = "D", harmonics: int = 5,
                      rest: float = 1.0, fraction: float = 0.5, pos_margin: float = 0.2, clearance: float = 0.15,
                      noise: Any = None, neff_rate: float = NEFF_RATE, reference: Any = None, seed: int = 0,
                      time_budget: float = 45.0, max_evaluations: int | None = None,
                      verbose: bool = False) -> Design:
    """Design an excitation for ``effects`` (names; those of the ``separate`` groups are added). ``reference`` is a
    ProcessedLog (the log that raised the question) or None (the generic excitation of the same duration). The
    search stops after ``time_budget`` s of wall time or ``max_evaluations`` criterion evaluations, whichever comes
    first (a number of evaluations makes the design the same on any machine). Raises ValueError naming a bad
    input."""
    from scipy.optimize import minimize

    from franka_vs_gym.model.franka_model import FrankaModel
    from franka_vs_gym.validation.compare import progress
    from franka_vs_gym.validation.effects import get_effect
    from franka_vs_gym.validation.hidden import TORQUE_NOISE

    t0 = time.perf_counter()
    separate = [list(g) for g in (separate or [])]
    names: list[str] = []
    for n in list(effects) + [x for g in separate for x in g]:
        e = get_effect(n)
        if e.name not in names:
            names.append(e.name)
    if not names:
        raise ValueError("name at least one effect to design the excitation for")
    for g in separate:
        if len(g) < 2:
            raise ValueError(f"--separate needs two or more effects, got {g}")
    separate = [[get_effect(n).name for n in g] for g in separate]
    if criterion not in ("D", "E"):
        raise ValueError(f"criterion must be 'D' or 'E', got {criterion!r}")
    if not duration >= 2 * rest + 4.0:
        raise ValueError(f"duration {duration:g} s leaves less than 4 s of motion between the {rest:g} s rests")
    if not 0 < fraction <= 1:
        raise ValueError(f"fraction of the limits must be in (0, 1], got {fraction}")
    if harmonics < 2:
        raise ValueError(f"harmonics must be >= 2, got {harmonics}")
    cfg = config if config is not None else ModelConfig()
    model = FrankaModel(cfg)
    effs = [get_effect(n) for n in names]
    sig = np.asarray(TORQUE_NOISE if noise is None else noise, dtype=float)
    lim = Limits.of(model, fraction, pos_margin, clearance)
    kin = Kinematics(model)

    moving = duration - 2 * rest
    periods = max(1, int(round(moving / PERIOD)))
    period = moving / periods

    # the reference: the log that raised the question, or the generic excitation of the same duration
    progress("evaluating the reference motion", verbose)
    if reference is None:
        F_ref, ref_cols = motion_information(generic_motion(duration, seed), cfg, effs, sig, DESIGN_SAMPLES)
        ref_what = f"generic excitation of {duration:g} s (the generators' random Fourier motion, seed {seed})"
    else:
        sig = np.asarray(reference.noise if noise is None else noise, dtype=float)
        F_ref, ref_cols = log_information(reference, cfg, effs, sig)
        ref_what = (f"the log {reference.log.source or '(in memory)'} "
                    f"({float(reference.time[-1] - reference.time[0]):.1f} s)")
    rng = np.random.default_rng(seed)
    L = harmonics
    lo, hi = lim.q_min, lim.q_max
    neutral = cfg.robot.neutral()
    t_lin = rest + np.linspace(0.0, period, int(period * 200), endpoint=False)
    t_kin = np.concatenate([[0.0], rest + np.linspace(0.0, period, 30, endpoint=False)])
    d_ref = np.sqrt(np.maximum(np.diag(F_ref), 1e-12 * max(float(np.diag(F_ref).max()), 1e-300)))

    def unpack(x: np.ndarray) -> FourierMotion:
        a = np.zeros((7, L))
        b = np.zeros((7, L))
        k = 7
        a[:, 1:] = x[k:k + 7 * (L - 1)].reshape(7, L - 1)
        k += 7 * (L - 1)
        b[:, 1:] = x[k:k + 7 * (L - 1)].reshape(7, L - 1)
        return FourierMotion(np.clip(x[:7], lo + 1e-3, hi - 1e-3), a, b, period, periods, rest).constrained()

    def within(m: FourierMotion) -> FourierMotion | None:
        f = max_scale(m, lim, kin, t_lin, t_kin)
        return m.scaled(0.999 * f) if f > 0 else None

    def crit(F: np.ndarray) -> float:
        Fn = F / np.outer(d_ref, d_ref)
        w = np.maximum(np.linalg.eigvalsh(0.5 * (Fn + Fn.T)), 1e-12)
        return -float(np.mean(np.log(w))) if criterion == "D" else -float(np.log(w[0]))

    n_eval = [0]
    best: dict[str, Any] = {"f": np.inf, "m": None}
    deadline = t0 + time_budget

    def objective(x: np.ndarray) -> float:
        if best["m"] is not None and (time.perf_counter() > deadline
                                      or (max_evaluations is not None and n_eval[0] >= max_evaluations)):
            raise _OutOfTime
        n_eval[0] += 1
        m = within(unpack(x))
        if m is None:
            return 1e3
        f = crit(motion_information(m, cfg, effs, sig, SEARCH_SAMPLES)[0])
        if f < best["f"]:
            best["f"], best["m"] = f, m
        return f

    # starting points: random harmonics (amplitudes falling as 1/l) about centres near the neutral pose, each
    # scaled to the limits; the best one is refined
    progress(f"designing a {duration:g} s excitation for {', '.join(names)} ({criterion}-optimal)", verbose)
    starts = []
    for _ in range(8):
        c = np.clip(neutral + rng.uniform(-0.4, 0.4, 7), lo + 0.3, hi - 0.3)
        amp = rng.normal(0, 1, (2, 7, L - 1)) / np.arange(2, L + 1)
        starts.append(np.concatenate([c, amp[0].ravel(), amp[1].ravel()]))
    try:
        fs = [objective(x) for x in starts]
        x0 = starts[int(np.argmin(fs))]
        bound = [(float(a), float(b)) for a, b in zip(lo, hi, strict=True)] + [(-2.0, 2.0)] * (14 * (L - 1))
        minimize(objective, x0, method="L-BFGS-B", bounds=bound, options={"maxiter": 500, "eps": 1e-5})
    except _OutOfTime:
        pass
    motion = best["m"]
    if motion is None:
        raise ValueError("no motion within the limits was found: lower --clearance or the position margin")
    # the result within every limit on a fine grid over the whole motion (200 Hz; kinematics at 25 Hz)
    t_check = np.linspace(0.0, duration, int(duration * 200) + 1)
    f = max_scale(motion, lim, kin, t_check, t_check[::8])
    if f < 1.0:
        motion = motion.scaled(0.999 * f)
    F, cols = motion_information(motion, cfg, effs, sig)
    widths = predicted_widths(F, neff_rate)
    widths_ref = predicted_widths(F_ref, neff_rate)
    groups = separate or ([names] if len(names) > 1 else [])
    col = {}
    if groups:
        col = {"designed": _collinearity(cols, groups), "reference": _collinearity(ref_cols, groups)}
    q, dq, ddq, dddq = motion.sample(t_check)
    full = Limits.of(model, 1.0, 0.0, 0.0)
    lims = {"fraction_of_limits": fraction, "position_margin_rad": pos_margin, "table_clearance_m": clearance,
            "peak_dq_over_limit": np.round((np.abs(dq) / full.dq_max).max(axis=0), 3).tolist(),
            "peak_ddq_over_limit": np.round((np.abs(ddq) / full.ddq_max).max(axis=0), 3).tolist(),
            "peak_dddq_over_limit": np.round((np.abs(dddq) / full.dddq_max).max(axis=0), 3).tolist(),
            "lowest_flange_m": round(float(kin.heights(q[::20])[:, 0].min()), 3),
            "lowest_end_effector_m": round(float(kin.heights(q[::20])[:, 1].min()), 3),
            # the robot's own limits the fractions refer to (what a report draws the motion against)
            "robot_limits": {"q_min_rad": full.q_min.tolist(), "q_max_rad": full.q_max.tolist(),
                             "dq_max_rad_per_s": full.dq_max.tolist(), "ddq_max_rad_per_s2": full.ddq_max.tolist(),
                             "dddq_max_rad_per_s3": full.dddq_max.tolist()}}
    seconds = time.perf_counter() - t0
    progress(f"designed in {seconds:.1f} s ({n_eval[0]} criterion evaluations)", verbose)
    return Design(motion, names, separate, criterion, ref_cols.names, ref_cols.owner, widths, widths_ref, ref_what,
                  sig, neff_rate, seconds, n_eval[0], col, lims)


def effect_widths(data, effects: list[str], config: ModelConfig, neff_rate: float = NEFF_RATE,
                  noise: Any = None) -> dict[str, float]:
    """Predicted 95 % widths of the effects' parameters on a recorded (processed) log, with the same noise model as
    the design (noise: the log's floor unless given)."""
    from franka_vs_gym.validation.effects import get_effect

    sig = np.asarray(data.noise if noise is None else noise, dtype=float)
    F, cols = log_information(data, config, [get_effect(n) for n in effects], sig)
    return dict(zip(cols.names, predicted_widths(F, neff_rate).tolist(), strict=True))


__all__ = ["Design", "design_excitation", "effect_widths"]
