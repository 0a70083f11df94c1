"""What every view of a run shows (the HTML report, the Markdown report, the MCAP log, the terminal), read from the
objects the workbench computed: :class:`~franka_vs_gym.validation.compare.CompareResult`,
:class:`~franka_vs_gym.validation.results.Diagnosis` and :class:`~franka_vs_gym.validation.results.FitResult`.

Nothing here fits or tests again; it arranges numbers for display: units from the parameter names, the status of a
ranking entry in words, the signals on one timeline, the phase of a periodic finding, and decimation of long traces
for display (a min/max envelope per bucket, so that peaks stay visible).
Fields that newer versions of the workbench add (confidence intervals ``params_ci95``, ``correlations``,
``unidentifiable``, ``Diagnosis.ambiguous`` and ``changes``) are shown when present.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

# parameter-name suffix -> unit shown (the workbench writes units into the names: viscous_Nms_per_rad, mass_kg, ...)
UNITS = (("_Nms_per_rad", "Nm s/rad"), ("_rad_per_s", "rad/s"), ("_s_per_rad", "s/rad"), ("_m_per_s2", "m/s^2"),
         ("_kgm2", "kg m^2"), ("_kgm", "kg m"), ("_Nm", "Nm"), ("_kg", "kg"), ("_deg", "deg"), ("_m", "m"), ("_s", "s"))
JOINT_LIST = 7


def unit_of(name: str) -> tuple[str, str]:
    """(label without the unit suffix, unit) of a parameter name such as ``viscous_Nms_per_rad``."""
    for suffix, unit in UNITS:
        if name.endswith(suffix):
            return name[: -len(suffix)], unit
    if name in ("mu", "coef") or name.endswith(("_change", "_scale")):
        return name, "-"
    return name, ""


def fmt(v: Any, nd: int = 4) -> str:
    """A number (or list of numbers) for a table cell: 4 significant digits, '-' for missing."""
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float, np.floating, np.integer)):
        f = float(v)
        return "-" if not math.isfinite(f) else f"{f:.{nd}g}"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(fmt(x, nd) for x in v) + "]"
    return str(v)


@dataclass
class ParamRow:
    """One row of the parameter table: effect, parameter, unit, value(s) (scalar or per joint), interval(s)."""

    effect: str
    name: str
    unit: str
    value: Any
    ci95: Any = None
    note: str = ""


def _ci_for(ci: Any, key: str) -> Any:
    if isinstance(ci, dict):
        return ci.get(key)
    return None


def param_rows(params: dict[str, Any], effect: str, ci95: Any = None, skip=("joints", "problems")) -> list[ParamRow]:
    rows = []
    for k, v in params.items():
        if k in skip or isinstance(v, str):
            continue
        label, unit = unit_of(k)
        rows.append(ParamRow(effect, label, unit, v, _ci_for(ci95, k)))
    return rows


def effect_extras(obj: Any) -> dict[str, Any]:
    """Identifiability fields of a selected effect or fit, when the workbench provides them."""
    d = obj if isinstance(obj, dict) else {}
    out = {}
    for k in ("params_ci95", "correlations", "unidentifiable"):
        v = d.get(k) if d else getattr(obj, k, None)
        if v is not None and v != {} and v != []:
            out[k] = v
    return out


def selected_params(diagnosis) -> list[ParamRow]:
    rows = []
    for s in diagnosis.selection:
        ex = effect_extras(s)
        rows += param_rows(s.params, s.effect, ex.get("params_ci95"))
    return rows


def fit_params(fit) -> list[ParamRow]:
    rows = []
    ci_all = getattr(fit, "params_ci95", None) or {}
    for eff, p in fit.params.items():
        ci = ci_all.get(eff) if isinstance(ci_all, dict) else None
        if ci is None and isinstance(p, dict):
            ci = p.get("params_ci95") or p.get("ci95")
        rows += param_rows({k: v for k, v in p.items() if k not in ("params_ci95", "ci95")}, eff, ci)
        if p.get("problems"):
            rows[-1].note = "; ".join(p["problems"]) if rows else ""
    return rows


def value_text(r: ParamRow, nd: int = 4, full: bool = False) -> str:
    """'0.312 [0.30, 0.33] deg' or per joint 'j0 0.12, j2 0.3 Nm' (zeros and missing values of unused joints left
    out)."""
    v, ci = r.value, r.ci95
    unit = f" {r.unit}" if r.unit and r.unit != "-" else ""
    if isinstance(v, list) and len(v) == JOINT_LIST and all(not isinstance(x, list) for x in v):
        parts = []
        for j, x in enumerate(v):
            if x is None or (isinstance(x, (int, float)) and (not math.isfinite(float(x)) or float(x) == 0.0)):
                continue  # a joint the effect does not act on
            c = ci[j] if isinstance(ci, list) and len(ci) == JOINT_LIST else None
            parts.append(f"j{j} {fmt(x, nd)}" + (f" [{fmt(c[0], 3)}, {fmt(c[1], 3)}]" if _pair(c) else ""))
        return (", ".join(parts) or "0") + unit
    c = f" [{fmt(ci[0], 3)}, {fmt(ci[1], 3)}]" if _pair(ci) else (f" (95%: {fmt(ci, 3)})" if ci is not None else "")
    if not full and isinstance(v, list) and len(v) > 2 * JOINT_LIST:  # e.g. 43 base parameters: the size, not all
        a = np.abs(np.asarray([x for x in v if isinstance(x, (int, float))], float))
        return f"{len(v)} values, largest {fmt(a.max() if a.size else None, 3)}{unit} (all in --json){c}"
    return f"{fmt(v, nd)}{c}{unit}"


def _pair(c: Any) -> bool:
    return isinstance(c, (list, tuple)) and len(c) == 2 and all(isinstance(x, (int, float)) for x in c)


def ranking_status(c, selected: bool = False) -> str:
    """The state of a ranking entry (not in the selected set) in words: what the numbers and the problems mean
    together. ``selected``: a selection ran and chose other effects."""
    problems = list(getattr(c, "problems", []) or [])
    if not c.plausible:
        return "rejected: implausible values"
    if not c.significant:
        return "not significant"
    kept = "significant alone on its kept joints (implausible joints dropped)" if problems else "significant alone"
    return kept + ("; not needed once the selected effects are in" if selected else "")


def verdict_lines(diagnosis) -> list[str]:
    """The verdict with its fitted values first, as a person reads it."""
    d = diagnosis
    lines = [f"verdict: {d.verdict}" + ("" if d.selection else " (no effect explains the residual above the noise)")]
    for s in d.selection:
        vals = "; ".join(f"{r.name} {value_text(r)}" for r in param_rows(s.params, s.effect,
                                                                          effect_extras(s).get("params_ci95")))
        lines.append(f"  {s.effect} (joints {s.joints}): {vals}")
        ex = effect_extras(s)
        if ex.get("unidentifiable"):
            lines.append(f"    not identifiable from this log: {fmt(ex['unidentifiable'])}")
    for c in getattr(d, "changes", None) or []:
        lines.append("  " + (c.text() if hasattr(c, "text") else f"the model changes: {fmt(c)}"))
    for a in getattr(d, "ambiguous", None) or []:
        lines.append("  " + (a.text() if hasattr(a, "text") else f"ambiguous: {fmt(a)}"))
    if d.unexplained is not None:
        lines.append(f"explained: {'yes' if d.unexplained.explained else 'NO'} - {' '.join(d.unexplained.text)}")
    return lines


def fit_lines(fit) -> list[str]:
    """The fitted values, one line per effect (not one number per line)."""
    lines = []
    for eff in fit.effects:
        p = fit.params.get(eff, {})
        rows = [r for r in fit_params(fit) if r.effect == eff]
        lines.append(f"  {eff} (joints {p.get('joints', '-')}): " + "; ".join(f"{r.name} {value_text(r)}"
                                                                             for r in rows))
        if p.get("problems"):
            lines.append(f"    implausible: {'; '.join(p['problems'])}")
    return lines


def correlation_lines(correlations: list[dict[str, Any]] | None, unidentifiable: list[str] | None = None,
                      verbose: bool = False, top: int = 5) -> list[str]:
    """Strongly correlated parameter pairs (the strongest ``top`` unless ``verbose``) and the combinations the log
    cannot identify, in words. A pair listed twice (under each of two effects, in either order) is said once."""
    unique: dict[frozenset, dict[str, Any]] = {}
    for c in correlations or []:
        unique.setdefault(frozenset((c["a"], c["b"])), c)
    corr = sorted(unique.values(), key=lambda c: -abs(c["r"]))
    shown = corr if verbose else corr[:top]
    lines = [f"  correlated: {c['a']} and {c['b']} (r = {c['r']})" for c in shown]
    if len(corr) > len(shown):
        lines.append(f"  correlated: {len(corr) - len(shown)} more pairs with abs(r) > 0.9 (--verbose or --json)")
    lines += [f"  not identifiable: {u}" for u in (unidentifiable or [])]
    return lines


def next_command(log_source: str, diagnosis=None, fit=None, model_file: str | None = None, flags: str = "") -> str:
    """The one command to run next. ``flags``: options of this run the next one needs as well (``--topic``,
    ``--rate`` ...); a robot given with ``--robot`` is carried over from the run's configuration."""
    import shlex

    src = shlex.quote(str(log_source or "LOG"))
    cfg = fit.after if fit is not None else getattr(diagnosis, "config", None)
    notes = getattr(cfg, "notes", None) or {}
    if cfg is not None and str(notes.get("robot_source", "")).startswith("--robot") and "--robot" not in flags:
        flags = f"--robot {cfg.robot.name} {flags}".strip()
    flags = f" {flags}" if flags else ""
    if fit is not None:
        return (f"franka-vs diagnose {src} --model {shlex.quote(model_file or 'calibrated.json')}{flags} "
                "--report report_after")
    if diagnosis is not None:
        if diagnosis.selection:
            names = ",".join(s.effect for s in diagnosis.selection)
            return f"franka-vs fit {src} --add {names} -o calibrated.json{flags} --report fit_report"
        return f"franka-vs compare {src}{flags} --report compare_report"
    return f"franka-vs diagnose {src}{flags} --report diagnose_report"


# ----------------------------------------------------------------------------------------------- signals
@dataclass
class Timeline:
    """The signals of one run on one time grid (s): measured torque, model before (and after), residual(s), the
    noise floor, each effect's contribution (N, 7) Nm, and the replay (q, tau) when there is one."""

    time: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    tau: np.ndarray
    model_before: np.ndarray
    noise: np.ndarray
    model_after: np.ndarray | None = None
    after_label: str = ""
    contributions: dict[str, np.ndarray] = field(default_factory=dict)
    contribution_time: np.ndarray | None = None
    replay_q: np.ndarray | None = None
    replay_tau: np.ndarray | None = None
    replay_mode: str = ""
    t0_abs: float = 0.0

    @property
    def residual_before(self) -> np.ndarray:
        return self.tau - self.model_before

    @property
    def residual_after(self) -> np.ndarray | None:
        return None if self.model_after is None else self.tau - self.model_after


def timeline(res, diagnosis=None, fit=None) -> Timeline:
    """The signals from the comparison (whole log), the diagnosis (the selected set's residual on the analysed
    samples) or the fit (the calibrated model on the whole log)."""
    data = res.data
    tl = Timeline(data.time, data.q, data.dq, data.tau, data.tau - res.residual, data.noise)
    if fit is not None:
        tl.model_before = data.tau - fit.residual_before if len(fit.residual_before) == data.n else tl.model_before
        if len(fit.residual_after) == data.n:
            tl.model_after = data.tau - fit.residual_after
            tl.after_label = "calibrated model (" + ", ".join(fit.effects) + ")"
        c = getattr(fit, "contributions", None) or {}
        tl.contributions, tl.contribution_time = dict(c), getattr(fit, "contribution_time", None)
    elif diagnosis is not None:
        ctx_data = diagnosis.context.data
        c = getattr(diagnosis, "contributions", None) or {}
        added = None
        if c:  # the selected effects' torque, on the analysed samples (possibly a decimated copy of the log)
            added = sum(np.asarray(v, float) for v in c.values())
        elif diagnosis.residual is not None and diagnosis.selection:
            added = diagnosis.context.residual - diagnosis.residual
        if added is not None and diagnosis.selection:
            if ctx_data.n != data.n:  # onto the whole log's grid (the effects' torque is smooth)
                added = np.stack([np.interp(data.time, ctx_data.time, added[:, j]) for j in range(7)], 1)
            tl.model_after = tl.model_before + added
            tl.after_label = "model + selected effects (" + ", ".join(diagnosis.selected) + ")"
        tl.contributions, tl.contribution_time = dict(c), ctx_data.time
    rp = res.replay
    if rp is not None:
        tl.replay_q, tl.replay_tau, tl.replay_mode = rp.q, rp.tau, rp.mode
    t_log = np.asarray(data.log.time, float)
    if len(t_log) and t_log[0] > 1e8:  # the log carries clock time (s since 1970): keep it, for other recordings
        tl.t0_abs = float(t_log[0])
    return tl


def envelope(t: np.ndarray, y: np.ndarray, max_points: int = 2000) -> tuple[np.ndarray, np.ndarray]:
    """Decimate a trace for display keeping its extremes: each of ``max_points // 2`` buckets contributes its
    minimum and its maximum, in time order. Short traces are returned as they are. NaN samples are kept out."""
    n = len(t)
    if n <= max_points:
        return t, y
    nb = max_points // 2
    s = int(math.ceil(n / nb))
    nb = int(math.ceil(n / s))
    pad = nb * s - n
    yp = np.concatenate([y, np.full(pad, np.nan)]) if pad else y
    tp = np.concatenate([t, np.full(pad, t[-1])]) if pad else t
    Y = yp.reshape(nb, s)
    T = tp.reshape(nb, s)
    ok = np.isfinite(Y).any(axis=1)
    Yn = np.where(np.isfinite(Y), Y, np.inf)
    imin = np.argmin(Yn, axis=1)
    imax = np.argmax(np.where(np.isfinite(Y), Y, -np.inf), axis=1)
    first = np.minimum(imin, imax)
    second = np.maximum(imin, imax)
    rows = np.arange(nb)
    tt = np.stack([T[rows, first], T[rows, second]], 1)[ok].ravel()
    yy = np.stack([Y[rows, first], Y[rows, second]], 1)[ok].ravel()
    return tt, yy


def thin(n: int, max_points: int) -> np.ndarray:
    """Evenly spaced indices (at most ``max_points``) for scatter plots."""
    return np.arange(0, n, max(1, int(math.ceil(n / max_points))))


_PERIOD_Q = re.compile(r"period\s+([0-9.eE+-]+)\s*rad")
_FREQ_T = re.compile(r"^\s*([0-9.eE+-]+)\s*Hz")


def phase_of(group: str, detail: str) -> tuple[float, str] | None:
    """For a periodic finding, the period it reports and the unit of x: (period, "rad") for a periodic function of
    the joint position, (1/f, "s") for a periodic disturbance in time; None otherwise."""
    if group == "periodic_q":
        m = _PERIOD_Q.search(detail or "")
        if m:
            return float(m.group(1)), "rad"
    if group == "periodic_t":
        m = _FREQ_T.search(detail or "")
        if m and float(m.group(1)) > 0:
            return 1.0 / float(m.group(1)), "s"
    return None


@dataclass
class FindingView:
    """What one joint's strongest unexplained structure is plotted against: x (the phase in degrees for a periodic
    finding), the residual, the noise floor, the axis label and a title."""

    joint: int
    group: str
    x: np.ndarray
    r: np.ndarray
    noise: float
    xlabel: str
    title: str


def finding_views(diagnosis) -> list[FindingView]:
    """Each joint's strongest remaining structure against what it follows; a periodic one against the phase of its
    period, so the period is visible."""
    from franka_vs_gym.validation.structure import FOLLOWS

    u = getattr(diagnosis, "unexplained", None)
    if u is None or not u.plot_data:
        return []
    out = []
    for j in sorted(u.plot_data):
        group, x, r, nf = u.plot_data[j]
        detail = next((f.detail for f in u.findings if f.joint == j and f.group == group), "")
        ph = phase_of(group, detail)
        if ph is not None:
            period, unit = ph
            xs = np.mod(np.asarray(x, float), period) / period * 360.0
            label = f"phase of the {period:.3g} {unit} period (deg)"
        else:
            xs = np.asarray(x, float)
            label = "time (s)" if group in ("slow", "time", "step_drift") else FOLLOWS.get(group, group)
        if group == "slow":
            title = f"joint {j}: slow residual (below the filter cutoff), no single variable of the joint"
        else:
            title = f"joint {j}: follows {FOLLOWS.get(group, group)}" + (f" ({detail})" if detail else "")
        out.append(FindingView(j, group, xs, np.asarray(r, float), float(nf[0]), label, title))
    return out


def binned_mean(x: np.ndarray, r: np.ndarray, bins: int = 36) -> tuple[np.ndarray, np.ndarray]:
    """Mean of r in equal-width bins of x (NaN in empty bins): the curve drawn over a scatter."""
    if len(x) == 0:
        return x, r
    edges = np.linspace(float(np.min(x)), float(np.max(x)) + 1e-12, bins + 1)
    k = np.clip(np.digitize(x, edges) - 1, 0, bins - 1)
    cnt = np.bincount(k, minlength=bins)
    s = np.bincount(k, weights=r, minlength=bins)
    centers = 0.5 * (edges[:-1] + edges[1:])
    return centers, np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)  # NaN: the curve breaks over empty bins


__all__ = ["FindingView", "ParamRow", "Timeline", "binned_mean", "effect_extras", "envelope", "finding_views",
           "fit_lines", "fit_params", "fmt", "next_command", "param_rows", "phase_of", "ranking_status",
           "selected_params", "thin", "timeline", "unit_of", "value_text", "verdict_lines"]
