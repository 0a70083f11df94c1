"""The report of a designed excitation (``franka-vs excite --report DIR``): ``report.html`` (interactive, the same
look and machinery as the other reports), ``report.md`` and its PNG figures.

It shows what ``excite`` computed, nothing is computed again: the designed trajectory per joint (the rows of
``trajectory.csv``) against the robot's position, velocity and acceleration limits and the fraction of them the
design was allowed; the predicted 95 % interval width of every parameter, designed against the reference motion
(the log that raised the question, or the generic excitation of the same duration); what the motion tells apart
(the collinearity of the effects' torque signatures, designed and reference); and the commands that play it on
``franka-vs serve`` and on the robot and read the recording back.
"""

from __future__ import annotations

import html as _html
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.validation.report.content import envelope, fmt, unit_of

# what a design column of an effect without parameter names is (effect -> (label per column, unit))
_COLUMNS = {"viscous_friction": (["F_v"], "Nm s/rad"), "coulomb_friction": (["F_c"], "Nm"),
            "stribeck_friction": (["F_s"], "Nm"), "asymmetric_friction": (["F_plus", "F_minus"], "Nm"),
            "torque_offset": (["offset"], "Nm"), "armature": (["armature"], "kg m^2"),
            "load_dependent_friction": (["mu"], "-"), "link_mass": (["mass scale"], "-")}
_NAME = re.compile(r"^(?P<effect>[^.\[]+)(?:\.(?P<param>[^\[]+))?(?:\[(?P<joint>\d+)\])?$")


def parameter(name: str) -> tuple[str, str, int | None, str]:
    """(effect, parameter label, joint or None, unit) of a design parameter name such as ``viscous_friction[3]``,
    ``payload.m_kg``, ``sigmoid_friction.phi1_Nm[2]`` or ``asymmetric_friction.c1[0]``."""
    m = _NAME.match(name)
    if m is None:
        return name, name, None, ""
    eff, par, j = m.group("effect"), m.group("param"), m.group("joint")
    joint = int(j) if j is not None else None
    labels, unit = _COLUMNS.get(eff, ([], ""))
    if par is None:
        return eff, labels[0] if labels else eff, joint, unit
    if par.startswith("c") and par[1:].isdigit() and labels:
        k = int(par[1:])
        return eff, labels[k] if k < len(labels) else par, joint, unit
    if eff == "gravity_tilt":
        return eff, par, joint, "m/s^2"
    label, u = unit_of(par)
    return eff, label, joint, u or unit


@dataclass
class WidthRow:
    name: str
    effect: str
    label: str
    joint: int | None
    unit: str
    designed: float
    reference: float

    @property
    def ratio(self) -> float:
        """reference / designed: how many times narrower the designed motion's interval is predicted to be."""
        a, b = self.designed, self.reference
        if math.isfinite(a) and math.isfinite(b) and a > 0:
            return b / a
        if not math.isfinite(b) and math.isfinite(a):
            return math.inf  # the reference cannot identify it, the design can
        return math.nan


@dataclass
class ExciteView:
    """What the excitation report shows, read from ``excite``'s results: the Design (or its excite.json dict) and
    the rows of trajectory.csv (time, q_d, dq_d, ddq_d)."""

    design: dict[str, Any]
    table: np.ndarray
    folder: str
    seconds: float

    @property
    def time(self) -> np.ndarray:
        return self.table[:, 0]

    def signal(self, k: int) -> np.ndarray:
        """q (0), dq (1) or ddq (2), (n, 7)."""
        return self.table[:, 1 + 7 * k: 8 + 7 * k]

    @property
    def robot(self) -> dict[str, np.ndarray]:
        r = self.design["limits"].get("robot_limits") or {}
        return {k: np.asarray(v, float) for k, v in r.items()}

    @property
    def fraction(self) -> float:
        return float(self.design["limits"]["fraction_of_limits"])

    @property
    def margin(self) -> float:
        return float(self.design["limits"]["position_margin_rad"])

    def widths(self) -> list[WidthRow]:
        rows = []
        for name, w in self.design["predicted_ci95_width"].items():
            eff, label, joint, unit = parameter(name)
            a = math.inf if w["designed"] is None else float(w["designed"])
            b = math.inf if w["reference"] is None else float(w["reference"])
            rows.append(WidthRow(name, eff, label, joint, unit, a, b))
        return rows

    def question(self) -> str:
        d = self.design
        q = []
        if d["separate"]:
            q.append("tell apart " + "; ".join(" and ".join(g) for g in d["separate"]))
        alone = [e for e in d["effects"] if not any(e in g for g in d["separate"])]
        if alone or not q:
            q.append("identify the parameters of " + ", ".join(alone or d["effects"]))
        return ", and ".join(q)

    def ambiguity_lines(self) -> list[str]:
        """What the motion tells apart, in words, from the collinearity excite computed."""
        col = self.design.get("collinearity") or {}
        des, ref = col.get("designed", {}), col.get("reference", {})
        out = []
        for pair, c in des.items():
            a, b = pair.split("|")
            r = ref.get(pair)
            verdict = ("still hard to tell apart" if c > 0.95 else "better told apart than by the reference"
                       if r is not None and c < r - 0.02 else "told apart as well as by the reference"
                       if r is not None and abs(c - r) <= 0.02 else "worse told apart than by the reference"
                       if r is not None else "")
            out.append(f"{a} and {b}: " + (f"{verdict}; " if verdict else "")
                       + f"collinearity {c:.2f} on the designed motion"
                       + (f", {r:.2f} on the reference" if r is not None else "")
                       + " (cosine of the smallest angle between their torque signatures, 1 = indistinguishable)")
        return out

    def commands(self) -> list[tuple[str, str]]:
        """(what, command) to play the design on the simulator and the robot and read the recording back."""
        f = self.folder
        eff = ",".join(self.design["effects"])
        rec = f"{f}/excitation_pylibfranka_recorded.csv"
        return [("start the simulated robot (FCI on this machine)", "franka-vs serve --lockstep --no-camera &"),
                ("play and record it on the simulator", f"python {f}/play_excitation_pylibfranka.py 127.0.0.1"),
                ("on the robot (its address; or the franky script)",
                 f"python {f}/play_excitation_pylibfranka.py ROBOT_ADDRESS"),
                ("read the recording back: what the model lacks", f"franka-vs diagnose {rec} --report diagnosis/"),
                ("fit the effects in question, with their intervals",
                 f"franka-vs fit {rec} --add {eff} -o calibrated.json --report fit/")]

    def summary_lines(self) -> list[str]:
        out = []
        for s in self.design["summary"]:
            r = s["median_width_ratio_reference_over_designed"]
            out.append(f"{s['effect']}: 95% intervals predicted {fmt(r, 3)}x narrower than the reference's"
                       + (f" (median over its {s['parameters']} parameters)" if s["parameters"] > 1 else "")
                       + (f"; {s['unidentified_reference']} not identifiable from the reference"
                          if s.get("unidentified_reference") else "")
                       + (f"; {s['unidentified_designed']} not identifiable from the design"
                          if s.get("unidentified_designed") else ""))
        return out

    def limit_rows(self) -> list[list[str]]:
        lim = self.design["limits"]
        q = self.signal(0)
        rob = self.robot
        rows = []
        if "q_min_rad" in rob:
            rng = rob["q_max_rad"] - rob["q_min_rad"]
            room = np.minimum(q.min(axis=0) - rob["q_min_rad"], rob["q_max_rad"] - q.max(axis=0))
            rows.append(["closest to a position limit (rad)"] + [fmt(x, 3) for x in room])
            rows.append(["range used (of the joint's)"] + [fmt((q.max(axis=0) - q.min(axis=0))[j] / rng[j], 2)
                                                            for j in range(7)])
        rows.append(["peak velocity (of the limit)"] + [fmt(x, 3) for x in lim["peak_dq_over_limit"]])
        rows.append(["peak acceleration (of the limit)"] + [fmt(x, 3) for x in lim["peak_ddq_over_limit"]])
        rows.append(["peak jerk (of the limit)"] + [fmt(x, 3) for x in lim["peak_dddq_over_limit"]])
        return rows


def view(design, table: np.ndarray, folder: str | Path, seconds: float | None = None) -> ExciteView:
    """An ExciteView of a :class:`~franka_vs_gym.validation.excite.Design` (or its ``to_dict()``) and the rows of its
    trajectory.csv."""
    from franka_vs_gym.errors import UserError

    d = design.to_dict() if hasattr(design, "to_dict") else dict(design)
    if not (d.get("limits") or {}).get("robot_limits"):
        raise UserError("the design has no robot_limits (an excite.json of an older franka-vs): run "
                        "'franka-vs excite' again to report it")
    table = np.asarray(table, float)
    if table.ndim != 2 or table.shape[1] != 22:
        raise UserError(f"the trajectory must have 22 columns (time, q_d, dq_d, ddq_d), got shape {table.shape}")
    return ExciteView(d, np.asarray(table, float), str(folder), float(seconds if seconds is not None
                                                                       else d.get("design_seconds", 0.0)))


# ----------------------------------------------------------------------------------------------------- PNG
def _periods(motion: dict[str, Any]) -> str:
    k = int(motion["periods"])
    return f"{k} period{'s' if k != 1 else ''}"


def _pretty_width(x: float) -> str:
    return "not identifiable" if not math.isfinite(x) else fmt(x, 3)


def plot_trajectory(v: ExciteView, path: Path) -> Path:
    """Seven joint panels (2 x 4 grid): position, velocity and acceleration, each as a fraction of the robot's limit
    (position: -1 and 1 are the joint's limits, about the middle of its range), with the design's allowed fraction
    and position margin dashed."""
    from franka_vs_gym.validation.report.figures import _grid, _legend_cell, _pixels

    t = v.time
    rob = v.robot
    fig, axes, cell = _grid(f"Designed excitation against the robot's limits ({v.fraction:g} of the velocity and "
                            f"acceleration limits allowed)", sharex=True)
    npx = 2 * _pixels(fig, axes[0])
    q, dq, ddq = v.signal(0), v.signal(1), v.signal(2)
    mid = 0.5 * (rob["q_max_rad"] + rob["q_min_rad"])
    half = 0.5 * (rob["q_max_rad"] - rob["q_min_rad"])
    for j, ax in enumerate(axes):
        ax.plot(*envelope(t, (q[:, j] - mid[j]) / half[j], npx), color="C0", lw=1.1, label="position")
        ax.plot(*envelope(t, dq[:, j] / rob["dq_max_rad_per_s"][j], npx), color="C1", lw=0.9, label="velocity")
        ax.plot(*envelope(t, ddq[:, j] / rob["ddq_max_rad_per_s2"][j], npx), color="C2", lw=0.7, alpha=0.8,
                label="acceleration")
        for y in (-1.0, 1.0):
            ax.axhline(y, color="k", lw=0.8, label="limit" if y > 0 else None)
            ax.axhline(y * v.fraction, color="C1", lw=0.8, ls="--",
                       label=f"{v.fraction:g} of the velocity/acceleration limit" if y > 0 else None)
            ax.axhline(y * (1 - v.margin / half[j]), color="C0", lw=0.8, ls=":",
                       label=f"position margin {v.margin:g} rad" if y > 0 else None)
        ax.set_ylim(-1.08, 1.08)
        ax.set_title(f"joint {j}", fontsize=9)
        if j % 4 == 0:
            ax.set_ylabel("fraction of the limit", fontsize=8)
        if j >= 3:
            ax.set_xlabel("time (s)", fontsize=8)
    _legend_cell(cell, axes[0])
    fig.savefig(path)
    return path


def plot_widths(v: ExciteView, path: Path) -> Path:
    """Predicted 95 % interval widths per parameter, designed and reference (log scale; a parameter a motion cannot
    identify is marked at the right edge)."""
    from franka_vs_gym.validation.report.figures import _figure

    rows = v.widths()
    n = len(rows)
    h = min(40.0, 1.2 + 0.22 * n)
    fig = _figure((9, h))
    ax = fig.add_subplot()
    fig.subplots_adjust(left=0.3, right=0.97, bottom=0.7 / h + 0.02, top=1 - 0.5 / h)
    y = np.arange(n)[::-1]
    fin = [x for r in rows for x in (r.designed, r.reference) if math.isfinite(x) and x > 0]
    hi = max(fin) * 3 if fin else 1.0
    lo = min(fin) / 3 if fin else 0.1
    for k, (key, color, label) in enumerate((("reference", "0.6", "reference"), ("designed", "C0", "designed"))):
        vals = np.array([getattr(r, key) for r in rows])
        shown = np.where(np.isfinite(vals), vals, hi)
        ax.barh(y + (0.2 if k == 0 else -0.2), shown - lo, left=lo, height=0.4, color=color, label=label)
        for yy, x in zip(y, vals, strict=True):
            if not math.isfinite(x):
                ax.text(hi, yy + (0.2 if k == 0 else -0.2), " not identifiable", va="center", fontsize=6)
    ax.set_xscale("log")
    ax.set_xlim(lo, hi * 3)
    ax.set_yticks(y)
    ax.set_yticklabels([f"{r.name} ({r.unit})" if r.unit and r.unit != "-" else r.name for r in rows], fontsize=7)
    ax.set_ylim(-0.7, n - 0.3)
    ax.set_xlabel("predicted 95% interval width (in the parameter's unit)", fontsize=8)
    ax.set_title("Predicted 95% interval widths: designed motion vs reference", fontsize=10)
    ax.legend(loc="lower right", fontsize=8)
    ax.tick_params(axis="x", labelsize=7)
    fig.savefig(path)
    return path


# ----------------------------------------------------------------------------------------------------- Markdown
def markdown_excite(v: ExciteView, outdir: Path) -> Path:
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    d = v.design
    traj = plot_trajectory(v, out / "excitation_limits.png")
    wid = plot_widths(v, out / "predicted_widths.png")
    L = [f"# Designed excitation: {v.question()}", "",
         f"{d['criterion']}-optimal, {d['motion']['duration_s']:g} s ({_periods(d['motion'])} of "
         f"{d['motion']['period_s']:.3g} s between {d['motion']['rest_s']:g} s rests), designed in {v.seconds:.1f} s "
         f"({d['criterion_evaluations']} criterion evaluations). Reference: {d['reference']}. Noise model: "
         f"{d['noise_model']}.", ""]
    L += [f"- {s}" for s in v.summary_lines()] + [""]
    amb = v.ambiguity_lines()
    if amb:
        L += ["## What it tells apart", ""] + [f"- {a}" for a in amb] + [""]
    L += ["## Predicted 95% interval widths", "", "| parameter | unit | designed | reference | reference / designed |",
          "|---|---|---|---|---|"]
    for r in v.widths():
        L.append(f"| {r.name} | {r.unit or '-'} | {_pretty_width(r.designed)} | {_pretty_width(r.reference)} | "
                 f"{'-' if math.isnan(r.ratio) else fmt(r.ratio, 3)} |")
    L += ["", f"![predicted widths]({wid.name})", "", "## The motion against the robot's limits", "",
          "| | " + " | ".join(f"joint {j}" for j in range(7)) + " |", "|---" * 8 + "|"]
    L += ["| " + " | ".join(row) + " |" for row in v.limit_rows()]
    lim = d["limits"]
    L += ["", f"Lowest flange {lim['lowest_flange_m']} m over the table (clearance asked "
              f"{lim['table_clearance_m']} m), lowest end effector {lim['lowest_end_effector_m']} m.", "",
          f"![trajectory against the limits]({traj.name})", "", "## Run it", "", "```bash"]
    L += [line for what, cmd in v.commands() for line in (f"# {what}", cmd)] + ["```", ""]
    md = out / "report.md"
    md.write_text("\n".join(L))
    return md


# ----------------------------------------------------------------------------------------------------- HTML
def _esc(x: Any) -> str:
    return _html.escape(str(x))


def html_excite(v: ExciteView, outdir: Path) -> Path:
    from bokeh.embed import components
    from bokeh.models import ColumnDataSource, FactorRange, HoverTool
    from bokeh.plotting import figure
    from bokeh.resources import Resources
    from bokeh.transform import dodge

    from franka_vs_gym.validation.report.html import COLORS, CSS, PLOT_W, _Report, _table

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    d = v.design
    rob = v.robot
    t = v.time
    lim_v = d["limits"]
    # the joint shown first: the one closest to one of its limits (velocity or acceleration)
    j0 = int(np.argmax(np.maximum(lim_v["peak_dq_over_limit"], lim_v["peak_ddq_over_limit"])))
    R = _Report(j0)
    T = float(t[-1])
    span = np.array([0.0, T])
    specs = (("position", 0, "q (rad)", "q_min_rad", "q_max_rad"),
             ("velocity", 1, "dq (rad/s)", "dq_max_rad_per_s", None),
             ("acceleration", 2, "ddq (rad/s^2)", "ddq_max_rad_per_s2", None))
    for key, k, ylab, lo_key, hi_key in specs:
        s = R.section(key, "", "time (s)", ylab)
        s.titles = [f"joint {j}: designed {key} and the robot's limits" for j in range(7)]
        x = v.signal(k)
        s.trace(f"designed {key}", [(t, x[:, j]) for j in range(7)], COLORS["before"], j0=j0)
        if hi_key is not None:  # position: the joint's range, and the margin the design kept
            qmin, qmax = rob[lo_key], rob[hi_key]
            s.trace("joint limits", [(np.r_[span, np.nan, span], np.r_[qmin[j], qmin[j], np.nan, qmax[j], qmax[j]])
                                     for j in range(7)], "#000000", decimate=False, j0=j0)
            s.trace(f"limits - margin {v.margin:g} rad",
                    [(np.r_[span, np.nan, span], np.r_[qmin[j] + v.margin, qmin[j] + v.margin, np.nan,
                                                      qmax[j] - v.margin, qmax[j] - v.margin]) for j in range(7)],
                    COLORS["after"], width=1.0, decimate=False, j0=j0)
        else:
            m = rob[lo_key]
            s.trace("robot's limit", [(np.r_[span, np.nan, span], np.r_[m[j], m[j], np.nan, -m[j], -m[j]])
                                      for j in range(7)], "#000000", decimate=False, j0=j0)
            s.trace(f"{v.fraction:g} of it (allowed)",
                    [(np.r_[span, np.nan, span], v.fraction * np.r_[m[j], m[j], np.nan, -m[j], -m[j]])
                     for j in range(7)], COLORS["after"], width=1.0, decimate=False, j0=j0)
    R.selector()
    # predicted widths: designed and reference per parameter (log scale), a parameter a motion cannot identify
    # drawn at the right edge and said in the table
    rows = v.widths()
    fin = [x for r in rows for x in (r.designed, r.reference) if math.isfinite(x) and x > 0]
    hi = max(fin) * 3 if fin else 1.0
    lo = min(fin) / 3 if fin else 0.1
    names = [r.name for r in rows]
    h = int(min(2400, 110 + 26 * len(rows)))
    wf = figure(y_range=FactorRange(*names[::-1]), x_axis_type="log", x_range=(lo, hi * 2), width=PLOT_W, height=h,
                tools="xpan,xwheel_zoom,box_zoom,reset,save",
                title="Predicted 95% interval width per parameter: designed motion vs reference (log scale)")
    for which, color, shift in (("reference", "#9a9a9a", 0.2), ("designed", COLORS["before"], -0.2)):
        vals = [getattr(r, which) for r in rows]
        src = ColumnDataSource({"y": names, "right": [x if math.isfinite(x) else hi for x in vals],
                                "left": [lo] * len(vals), "text": [_pretty_width(x) for x in vals],
                                "unit": [r.unit or "-" for r in rows]})
        wf.hbar(y=dodge("y", shift, range=wf.y_range), left="left", right="right", height=0.38, color=color,
                legend_label=which, source=src, name=which)
    wf.add_tools(HoverTool(tooltips=[("", "$name"), ("parameter", "@y"), ("95% width", "@text @unit")]))
    wf.xaxis.axis_label = "predicted 95% interval width (in the parameter's unit)"
    wf.yaxis.major_label_text_font_size = "8pt"
    wf.legend.location = "bottom_right"
    wf.toolbar.logo = None
    R.roots["widths"] = wf
    script, divs = components(R.roots)
    js = Resources(mode="inline", components=["bokeh", "bokeh-widgets"]).render_js()
    mo = d["motion"]
    B = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
         f"<title>franka-vs excite: {_esc(', '.join(d['effects']))}</title>", f"<style>{CSS}</style>", js, script,
         "</head><body>", f"<h1>Designed excitation: {_esc(v.question())}</h1>",
         f'<p class="muted">{_esc(d["criterion"])}-optimal, {mo["duration_s"]:g} s ({_periods(mo)} of '
         f'{mo["period_s"]:.3g} s between {mo["rest_s"]:g} s rests), designed in {v.seconds:.1f} s '
         f'({d["criterion_evaluations"]} criterion evaluations). Reference: {_esc(d["reference"])}. Noise model: '
         f'{_esc(d["noise_model"])}. Drag to pan, wheel or box to zoom, hover for values.</p>',
         '<div class="verdict">' + "".join(f"<p>{_esc(s)}</p>" for s in v.summary_lines())
         + "".join(f"<p>{_esc(a)}</p>" for a in v.ambiguity_lines()) + "</div>",
         "<h2>Run it</h2><pre>" + "\n".join(f"# {_esc(what)}\n{_esc(cmd)}" for what, cmd in v.commands())
         + "</pre><p class='muted'>The scripts take the robot's address as their only argument and write the "
         "recording next to themselves (never over an earlier one); the same file runs against "
         "<code>franka-vs serve</code> and the robot.</p>",
         "<h2>Predicted 95% interval widths</h2>",
         "<p class='muted'>Each parameter's predicted interval on the designed motion against the reference's; "
         "shorter is better. A parameter a motion cannot identify is drawn to the right edge.</p>", divs["widths"],
         _table(["parameter", "unit", "designed", "reference", "reference / designed"],
                [[r.name, r.unit or "-", _pretty_width(r.designed), _pretty_width(r.reference),
                  "-" if math.isnan(r.ratio) else fmt(r.ratio, 3)] for r in rows]),
         f'<h2>The motion against the robot\'s limits</h2><div class="sticky">Joints shown: {divs["joints"]}</div>',
         f"<p class='muted'>The rows of trajectory.csv (1 kHz). Velocities and accelerations were allowed "
         f"{v.fraction:g} of the robot's limits, positions kept {v.margin:g} rad from the joint limits. Lowest flange "
         f"{_esc(lim_v['lowest_flange_m'])} m over the table (clearance asked {_esc(lim_v['table_clearance_m'])} m), "
         f"lowest end effector {_esc(lim_v['lowest_end_effector_m'])} m.</p>",
         _table(["", *[f"joint {j}" for j in range(7)]], v.limit_rows()),
         divs["position"], divs["velocity"], divs["acceleration"],
         "<h2>The motion</h2>", f"<p><code>{_esc(mo['form'])}</code></p>",
         _table(["", *[f"joint {j}" for j in range(7)]],
                [["centre (rad)"] + [fmt(x, 4) for x in mo["centre_rad"]]]),
         f'<script type="application/json" id="franka-vs-plots">{json.dumps(sorted(R.roots))}</script>',
         "</body></html>"]
    path = out / "report.html"
    path.write_text("\n".join(B), encoding="utf-8")
    return path


def excite_report(design, table: np.ndarray, outdir: str | Path, folder: str | Path,
                  seconds: float | None = None) -> Path:
    """Write report.html, report.md and its figures (excitation_limits.png, predicted_widths.png) of a design into
    ``outdir``; ``folder`` is where excite wrote the scripts (named in the commands). Returns report.html's path."""
    v = view(design, table, folder, seconds)
    markdown_excite(v, Path(outdir))
    return html_excite(v, Path(outdir))


__all__ = ["ExciteView", "excite_report", "html_excite", "markdown_excite", "parameter", "plot_trajectory",
           "plot_widths", "view"]
