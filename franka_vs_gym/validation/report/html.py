"""``report.html``: one self-contained, interactive report of a comparison, a diagnosis or a fit.

The file opens offline in any browser, without a server: the plots are Bokeh documents with Bokeh's JavaScript
inlined once (about 1.6 MB; plotly's offline bundle alone is 4.8 MB, which leaves no room in the 5 MB goal for the
data of a 30 s log at 1 kHz). Every plot zooms (box, wheel), pans and shows values on hover; the time plots of all
sections share their time axis; one row of buttons at the top chooses the joint every section shows (all joints'
samples are in the file; the first shown is the one with the most error above its noise floor). Long traces
are decimated for display with a min/max envelope per bucket (:func:`~.content.envelope`), so peaks stay visible.

Sections: the verdict with its fitted values and the command to run next; per-joint RMSE; measured and model torque
per joint, before and after; the residual over time with its noise band and against what it follows (a periodic
finding against the phase of its period); each selected effect's contribution; the parameter table with units (and
95% intervals when the workbench gives them); the ranking with its evidence and reasons for rejection; what stays
unexplained; the assumptions; the replay.
"""

from __future__ import annotations

import html as _html
import json
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.validation.report.content import (
    Timeline,
    effect_extras,
    envelope,
    finding_views,
    fit_params,
    fmt,
    next_command,
    ranking_status,
    selected_params,
    thin,
    timeline,
    value_text,
)

MAX_POINTS = 1600  # per displayed time trace (800 min/max buckets)
MAX_SCATTER = 2500  # per scatter panel
COLORS = {"measured": "#7f7f7f", "before": "#1f77b4", "after": "#d62728", "band": "#2ca02c", "sim": "#ff7f0e"}
EFFECT_COLORS = ("#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22", "#1f77b4", "#ff7f0e")
PLOT_W, PLOT_H = 1140, 300


def _esc(x: Any) -> str:
    return _html.escape(str(x))


def _table(header: list[str], rows: list[list[Any]], cls: str = "") -> str:
    h = "".join(f"<th>{_esc(c)}</th>" for c in header)
    body = "".join("<tr>" + "".join(f"<td>{_esc(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table>'


class _Section:
    """One interactive figure showing one joint at a time: every trace's samples for every joint are stored in the
    file (one data source per trace and joint); the joint selector swaps them into the displayed sources."""

    def __init__(self, key: str, title: str, x_label: str, y_label: str, x_range=None, height: int = PLOT_H,
                 time_axis: bool = True) -> None:
        from bokeh.models import HoverTool
        from bokeh.plotting import figure

        tools = "xpan,xwheel_zoom,box_zoom,reset,save" if time_axis else "pan,wheel_zoom,box_zoom,reset,save"
        args = dict(width=PLOT_W, height=height, title=title, tools=tools, output_backend="canvas")
        if x_range is not None:
            args["x_range"] = x_range
        f = figure(**args)
        f.add_tools(HoverTool(tooltips=[("", "$name"), ("x", "@x{0.000}"), ("y", "@y{0.000}")]))
        f.xaxis.axis_label, f.yaxis.axis_label = x_label, y_label
        f.title.text_font_size = "10pt"
        f.toolbar.logo = None
        self.key, self.fig = key, f
        self.disp: list[Any] = []  # displayed source of each trace
        self.store: list[list[Any]] = []  # [trace][joint] stored sources
        self.titles = [title] * 7
        self.x_labels = [x_label] * 7
        self.band = None
        self.band_noise = [0.0] * 7

    def trace(self, label: str, per_joint: list[tuple[np.ndarray, np.ndarray] | None], color: str, kind: str = "line",
              width: float = 1.3, alpha: float = 1.0, j0: int = 0, decimate: bool = True) -> None:
        """A trace given as (x, y) per joint (None: nothing on that joint). The joints' samples are stored as plain
        float32 arrays in the joint selector's arguments (no data-source model per joint: fewer models to build and
        serialise); the displayed source holds the shown joint's."""
        from bokeh.models import ColumnDataSource

        store = []
        for xy in per_joint:
            if xy is None:
                x = y = np.zeros(0)
            else:
                x, y = np.asarray(xy[0], float), np.asarray(xy[1], float)
                if kind == "line" and decimate:
                    x, y = envelope(x, y, MAX_POINTS)
                elif kind == "scatter":
                    idx = thin(len(x), MAX_SCATTER)
                    x, y = x[idx], y[idx]
            store.append({"x": x.astype(np.float32), "y": y.astype(np.float32)})
        disp = ColumnDataSource(dict(store[j0]))
        if kind == "line":
            self.fig.line("x", "y", source=disp, color=color, line_width=width, alpha=alpha, legend_label=label,
                          name=label)
        else:
            self.fig.scatter("x", "y", source=disp, color=color, size=3, alpha=alpha, legend_label=label, name=label)
        self.disp.append(disp)
        self.store.append(store)

    def noise_band(self, noise, j0: int) -> None:
        from bokeh.models import BoxAnnotation

        self.band_noise = [float(x) for x in noise]
        self.band = BoxAnnotation(bottom=-self.band_noise[j0], top=self.band_noise[j0], fill_color=COLORS["band"],
                                  fill_alpha=0.15, line_alpha=0)
        self.fig.add_layout(self.band)

    def finish(self, j0: int) -> Any:
        f = self.fig
        f.title.text = self.titles[j0]
        f.xaxis.axis_label = self.x_labels[j0]
        f.legend.location = "top_left"
        f.legend.click_policy = "hide"
        f.legend.label_text_font_size = "8pt"
        f.legend.background_fill_alpha = 0.6
        f.legend.orientation = "horizontal"
        return f


class _Report:
    def __init__(self, j0: int) -> None:
        self.j0 = j0
        self.sections: list[_Section] = []
        self.roots: dict[str, Any] = {}
        self.time_range = None

    def section(self, key: str, title: str, x_label: str, y_label: str, time_axis: bool = True,
                height: int = PLOT_H) -> _Section:
        s = _Section(key, title, x_label, y_label, self.time_range if time_axis else None, height, time_axis)
        if time_axis and self.time_range is None:
            self.time_range = s.fig.x_range
        self.sections.append(s)
        return s

    def selector(self) -> None:
        from bokeh.models import CustomJS, RadioButtonGroup

        for s in self.sections:
            self.roots[s.key] = s.finish(self.j0)
        w = RadioButtonGroup(labels=[f"joint {j}" for j in range(7)], active=self.j0)
        bands = [s for s in self.sections if s.band is not None]
        w.js_on_change("active", CustomJS(args={
            "disp": [d for s in self.sections for d in s.disp],
            "store": [st for s in self.sections for st in s.store],
            "figs": [s.fig for s in self.sections], "titles": [s.titles for s in self.sections],
            "xlabels": [s.x_labels for s in self.sections],
            "bands": [s.band for s in bands], "noise": [s.band_noise for s in bands]}, code="""
            const j = cb_obj.active;
            for (let i = 0; i < disp.length; i++) { disp[i].data = {x: store[i][j].x, y: store[i][j].y}; }
            for (let i = 0; i < figs.length; i++) {
                figs[i].title.text = titles[i][j];
                for (const ax of figs[i].below) { ax.axis_label = xlabels[i][j]; }
            }
            for (let i = 0; i < bands.length; i++) { bands[i].bottom = -noise[i][j]; bands[i].top = noise[i][j]; }
        """))
        self.roots["joints"] = w


def _per_joint(t: np.ndarray, Y: np.ndarray | None) -> list[tuple[np.ndarray, np.ndarray] | None]:
    if Y is None:
        return [None] * 7
    return [(t, Y[:, j]) for j in range(7)]


def _torque_section(R: _Report, tl: Timeline) -> None:
    s = R.section("torque", "", "time (s)", "torque (Nm)")
    s.titles = [f"joint {j}: measured and model torque" for j in range(7)]
    s.trace("measured tau_J", _per_joint(tl.time, tl.tau), COLORS["measured"], width=1.0, alpha=0.8, j0=R.j0)
    s.trace("model (before)" if tl.model_after is not None else "model", _per_joint(tl.time, tl.model_before),
            COLORS["before"], j0=R.j0)
    if tl.model_after is not None:
        s.trace("model (after)", _per_joint(tl.time, tl.model_after), COLORS["after"], j0=R.j0)


def _residual_section(R: _Report, tl: Timeline) -> None:
    s = R.section("residual", "", "time (s)", "residual (Nm)")
    s.titles = [f"joint {j}: residual tau_J - tau_model, +-noise floor {tl.noise[j]:.3f} Nm" for j in range(7)]
    s.noise_band(tl.noise, R.j0)
    ra = tl.residual_after
    s.trace("before" if ra is not None else "residual", _per_joint(tl.time, tl.residual_before), COLORS["before"],
            width=1.0,
            alpha=0.6 if ra is not None else 1.0, j0=R.j0)
    if ra is not None:
        s.trace("after", _per_joint(tl.time, ra), COLORS["after"], width=1.0, j0=R.j0)


def _follows_section(R: _Report, tl: Timeline, diagnosis) -> str:
    """Against what the residual follows: a joint's strongest unexplained finding (diagnosis; a periodic one against
    the phase of its period), else the joint velocity (the friction signature)."""
    from franka_vs_gym.validation.report.content import binned_mean

    views = {v.joint: v for v in (finding_views(diagnosis) if diagnosis is not None else [])}
    r = tl.residual_after if tl.residual_after is not None else tl.residual_before
    s = R.section("follows", "", "dq (rad/s)", "residual (Nm)", time_axis=False, height=PLOT_H + 60)
    pts, curve, noise = [], [], []
    for j in range(7):
        v = views.get(j)
        if v is not None:
            s.titles[j], s.x_labels[j] = v.title if len(v.title) < 110 else v.title[:107] + "...", v.xlabel
            pts.append((v.x, v.r))
            curve.append(binned_mean(v.x, v.r))
            noise.append(v.noise)
        else:
            s.titles[j] = (f"joint {j}: residual against joint velocity" + (" (nothing unexplained on this joint)"
                                                                            if diagnosis is not None else ""))
            pts.append((tl.dq[:, j], r[:, j]))
            curve.append(binned_mean(tl.dq[:, j], r[:, j]))
            noise.append(float(tl.noise[j]))
    s.noise_band(noise, R.j0)
    s.trace("residual", pts, COLORS["before"], kind="scatter", alpha=0.35, j0=R.j0)
    s.trace("binned mean", curve, COLORS["after"], width=2.0, j0=R.j0, decimate=False)
    if views:
        return (f"Joints {sorted(views)}: the residual left by the selected effects against what it still follows (a "
                "periodic finding against the phase of its period, one cycle from 0 to 360 deg). Other joints: "
                "against the joint velocity.")
    return ("The residual against the joint velocity (a line is viscous friction, a step at 0 Coulomb friction, a "
            "rounded step a sigmoid or Stribeck law).")


def _effects_section(R: _Report, tl: Timeline) -> None:
    if not tl.contributions:
        return
    t = tl.contribution_time if tl.contribution_time is not None else tl.time
    s = R.section("effects", "", "time (s)", "torque (Nm)")
    s.titles = [f"joint {j}: torque of each selected effect" for j in range(7)]
    for k, (name, c) in enumerate(tl.contributions.items()):
        c = np.asarray(c, float)
        if c.ndim == 2 and len(c) == len(t):
            s.trace(name, _per_joint(t, c), EFFECT_COLORS[k % len(EFFECT_COLORS)], j0=R.j0)


def _replay_section(R: _Report, tl: Timeline) -> None:
    if tl.replay_q is None:
        return
    s = R.section("replay", "", "time (s)", "q (rad)")
    s.titles = [f"joint {j}: replay in the MuJoCo plant ({tl.replay_mode})" for j in range(7)]
    s.trace("measured q", _per_joint(tl.time, tl.q), COLORS["measured"], j0=R.j0)
    s.trace("simulated q", _per_joint(tl.time, tl.replay_q), COLORS["sim"], j0=R.j0)


def _rmse_bars(R: _Report, res, fit, diagnosis) -> None:
    from bokeh.models import ColumnDataSource, FactorRange
    from bokeh.plotting import figure

    series = [("before" if (fit is not None or diagnosis is not None) else "model",
               res.rmse_tau if fit is None else fit.rmse_before)]
    if fit is not None:
        series.append(("after", fit.rmse_after))
    elif diagnosis is not None and diagnosis.rmse_tau_selected is not None and diagnosis.selection:
        series = [("before", diagnosis.rmse_tau), ("selected set (held out)", diagnosis.rmse_tau_selected)]
    series.append(("noise floor", res.noise_floor))
    xs = [(f"joint {j}", name) for j in range(7) for name, _ in series]
    vals = [float(v[j]) for j in range(7) for _, v in series]
    palette = {"before": COLORS["before"], "model": COLORS["before"], "noise floor": COLORS["band"]}
    cols = [palette.get(name, COLORS["after"]) for _ in range(7) for name, _ in series]
    f = figure(x_range=FactorRange(*xs, group_padding=0.6), width=PLOT_W, height=230,
               title="Torque RMSE per joint (Nm)", tools="pan,wheel_zoom,reset,save,hover",
               tooltips=[("", "@x"), ("RMSE (Nm)", "@top{0.000}")])
    f.vbar(x="x", top="top", width=0.9, color="color", legend_field="series",
           source=ColumnDataSource({"x": xs, "top": vals, "color": cols, "series": [x[1] for x in xs]}))
    f.xaxis.major_label_text_font_size = "0pt"  # the series are in the legend; the joints label the groups
    f.xaxis.group_text_font_size = "10pt"
    f.xgrid.grid_line_color = None
    f.legend.location = "top_right"
    f.legend.orientation = "horizontal"
    f.legend.label_text_font_size = "8pt"
    f.y_range.start = 0
    f.toolbar.logo = None
    R.roots["rmse"] = f


def _first_joint(tl: Timeline) -> int:
    """The joint shown first: the one with the most error above its noise floor."""
    excess = np.nanmean(tl.residual_before ** 2, axis=0) - tl.noise ** 2
    return int(np.nanargmax(excess)) if np.isfinite(excess).any() else 0


CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:0 auto;max-width:1180px;padding:0 16px 40px;
color:#222}
h1{font-size:1.5em;margin:.6em 0 .2em} h2{font-size:1.15em;margin:1.6em 0 .4em;border-bottom:1px solid #ddd}
.verdict{background:#f4f7fb;border-left:4px solid #1f77b4;padding:8px 14px;margin:10px 0}
.verdict.bad{border-left-color:#d62728}
.verdict p{margin:.3em 0} code,pre{background:#f2f2f2;padding:2px 5px;border-radius:3px}
pre{padding:8px;overflow-x:auto} table{border-collapse:collapse;margin:6px 0;font-size:.85em}
td,th{border:1px solid #ddd;padding:3px 7px;text-align:left;vertical-align:top} th{background:#f6f6f6}
.muted{color:#666;font-size:.9em} .sticky{position:sticky;top:0;background:#fff;z-index:10;padding:6px 0;
border-bottom:1px solid #eee} .plotcount{display:none}
"""


def _rmse_rows(res, fit, diagnosis) -> list[list[Any]]:
    rows = [["RMSE (Nm)"] + [fmt(x, 3) for x in res.rmse_tau], ["bias (Nm)"] + [fmt(x, 3) for x in res.mean_tau],
            ["noise floor (Nm)"] + [fmt(x, 3) for x in res.noise_floor]]
    if fit is not None:
        rows = [["before (Nm)"] + [fmt(x, 3) for x in fit.rmse_before],
                ["after (Nm)"] + [fmt(x, 3) for x in fit.rmse_after]] + rows[2:]
    elif diagnosis is not None and diagnosis.rmse_tau_selected is not None and diagnosis.selection:
        rows.insert(1, ["with the selected set, held out (Nm)"] + [fmt(x, 3) for x in diagnosis.rmse_tau_selected])
    if res.replay is not None:
        rp = res.replay
        rows += [[f"replay RMSE_q ({rp.mode}, mrad)"] + [fmt(x * 1e3, 3) for x in rp.rmse_q],
                 [f"replay RMSE_tau ({rp.mode}, Nm)"] + [fmt(x, 3) for x in rp.rmse_tau]]
    return rows


def _summary_html(res, diagnosis, fit, model_file: str | None) -> str:
    L = []
    src = res.data.log.source or "log"
    if diagnosis is not None:
        d = diagnosis
        bad = d.unexplained is not None and not d.unexplained.explained
        L.append(f'<div class="verdict{" bad" if bad else ""}"><p><b>Verdict: {_esc(d.verdict)}</b>'
                 + ("" if d.selection else " (no effect explains the residual above the noise)") + "</p>")
        for s in d.selection:
            rows = [r for r in selected_params(d) if r.effect == s.effect]
            L.append(f"<p><b>{_esc(s.effect)}</b> (joints {_esc(s.joints)}): "
                     + _esc("; ".join(f"{r.name} {value_text(r)}" for r in rows)) + "</p>")
        amb = getattr(d, "ambiguous", None)
        if amb:
            L.append(f"<p>Ambiguous: {_esc(amb if isinstance(amb, str) else json.dumps(amb, default=str))}</p>")
        if d.unexplained is not None:
            L.append(f"<p>Explained: <b>{'yes' if d.unexplained.explained else 'NO'}</b>. "
                     f"{_esc(' '.join(d.unexplained.text))}</p>")
        L.append("</div>")
    if fit is not None:
        tb, ta = (float(np.sqrt(np.mean(np.square(x)))) for x in (fit.rmse_before, fit.rmse_after))
        L.append(f'<div class="verdict"><p><b>Fitted: {_esc(", ".join(fit.effects) or "nothing")}</b>; total '
                 f"torque RMSE {tb:.3f} &rarr; {ta:.3f} Nm</p>")
        for eff in fit.effects:
            rows = [r for r in fit_params(fit) if r.effect == eff]
            joints = fit.params.get(eff, {}).get("joints")
            L.append(f"<p><b>{_esc(eff)}</b>" + (f" (joints {_esc(joints)})" if joints is not None else "") + ": "
                     + _esc("; ".join(f"{r.name} {value_text(r)}" for r in rows))
                     + "</p>")
        if fit.holdout is not None:
            h = fit.holdout
            L.append(f"<p>Held-out check ({_esc(h.get('split'))}): total RMSE {fmt(h.get('rmse_tau_total_before'))} "
                     f"&rarr; {fmt(h.get('rmse_tau_total_after'))} Nm"
                     + (f"; dropped {_esc(h['dropped'])}" if h.get("dropped") else "") + "</p>")
        L.append("</div>")
    if diagnosis is None and fit is None:
        L.append(f'<div class="verdict"><p><b>Total torque RMSE {res.rmse_tau_total:.3f} Nm</b> over '
                 f"{res.data.n} samples</p></div>")
    L.append(f"<p>Next: <code>{_esc(next_command(src, diagnosis, fit, model_file))}</code></p>")
    return "\n".join(L)


def _ranking_html(d) -> str:
    why = {}
    for n in d.notes:
        name, sep, w = n.partition(" not selected: ")
        if sep:
            why[name] = w
    sel = set(d.selected)
    rows = []
    for i, c in enumerate(d.ranking):
        state = "selected" if c.effect in sel else ranking_status(c, selected=bool(sel))
        reasons = "; ".join(list(c.problems) + ([why[c.effect]] if c.effect in why else []))
        rows.append([i + 1, c.effect, c.joints, f"{c.score:.1f}", state, fmt(np.round(c.removed_rms, 3).tolist(), 3),
                     fmt(np.round(c.rmse_tau_after, 3).tolist(), 3), reasons])
    return _table(["rank", "effect", "joints", "score", "status", "removes (Nm RMS, held out)",
                   "held-out RMSE after (Nm)", "problems, reason not selected"], rows)


def _params_html(rows) -> str:
    if not rows:
        return "<p class='muted'>No fitted parameters.</p>"
    has_ci = any(r.ci95 is not None for r in rows)
    out = []
    for r in rows:
        cells = [r.effect, r.name, r.unit or "-", value_text(r, full=True).removesuffix(f" {r.unit}")]
        if has_ci:
            cells.append(fmt(r.ci95, 3))
        cells.append(r.note)
        out.append(cells)
    return _table(["effect", "parameter", "unit", "value"] + (["95% interval"] if has_ci else []) + ["note"], out)


def _extras_html(objs: list[tuple[str, Any]], diagnosis) -> str:
    parts = []
    for name, o in objs:
        ex = effect_extras(o)
        for k in ("correlations", "unidentifiable"):
            if k in ex:
                parts.append(f"<p><b>{_esc(name)}</b> {_esc(k)}: <code>{_esc(json.dumps(ex[k], default=str))}"
                             "</code></p>")
    ch = getattr(diagnosis, "changes", None) if diagnosis is not None else None
    if ch:
        parts.append(f"<p>Changes: <code>{_esc(json.dumps(ch, default=str))}</code></p>")
    return "\n".join(parts)


def html_report(res, outdir: str | Path, diagnosis=None, fit=None, model_file: str | None = None,
                overwrite: bool = False) -> Path:
    """Write ``report.html`` into ``outdir`` (see the module docstring) from a CompareResult and, when given, the
    Diagnosis and FitResult of the same log. Refuses to overwrite an existing file unless ``overwrite``."""
    from bokeh.embed import components
    from bokeh.resources import Resources

    out = Path(outdir)
    path = out / "report.html"
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; choose another folder or pass overwrite=True (--force)")
    out.mkdir(parents=True, exist_ok=True)
    tl = timeline(res, diagnosis, fit)
    R = _Report(_first_joint(tl))
    _rmse_bars(R, res, fit, diagnosis)
    _torque_section(R, tl)
    _residual_section(R, tl)
    follows_text = _follows_section(R, tl, diagnosis)
    _effects_section(R, tl)
    _replay_section(R, tl)
    R.selector()
    script, divs = components(R.roots)
    js = Resources(mode="inline", components=["bokeh", "bokeh-widgets"]).render_js()
    src = res.data.log.source or "log"
    kind = "fit" if fit is not None else ("diagnosis" if diagnosis is not None else "comparison")
    rep = res.data.report
    B: list[str] = [
        "<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
        f"<title>franka-vs {kind}: {_esc(Path(str(src)).name)}</title>", f"<style>{CSS}</style>", js, script,
        "</head><body>",
        f"<h1>Model vs measurement ({kind}): {_esc(Path(str(src)).name)}</h1>",
        f'<p class="muted">{_esc(src)}: {rep.rows_in} rows in, {res.data.n} samples used at '
        f'{rep.settings["rate"]:.0f} Hz '
        f"({res.data.time[-1] - res.data.time[0]:.1f} s); zero-phase low-pass {rep.settings['cutoff']} Hz. "
        "Drag to pan, wheel or box to zoom, hover for values, click a legend entry to hide it.</p>",
        _summary_html(res, diagnosis, fit, model_file),
        f'<div class="sticky">Joints shown: {divs["joints"]}</div>',
        "<h2>Error per joint</h2>", divs["rmse"],
        _table(["", *[f"joint {j}" for j in range(7)]], _rmse_rows(res, fit, diagnosis)),
        "<h2>Measured and model torque</h2>",
        "<p class='muted'>Measured joint torque tau_J and the model's inverse dynamics on the measured motion"
        + (", before and after." if tl.model_after is not None else ".") + " Time axes are linked.</p>",
        divs["torque"],
        "<h2>Residual over time</h2><p class='muted'>tau_J - tau_model; the green band is +-the noise floor "
        "(measurement noise no model can remove).</p>", divs["residual"],
        "<h2>Residual against what it follows</h2>", f"<p class='muted'>{_esc(follows_text)}</p>", divs["follows"],
    ]
    if "effects" in divs:
        B += ["<h2>Each selected effect's contribution</h2><p class='muted'>The torque each effect adds to the "
              "model, fitted together with the others.</p>", divs["effects"]]
        if diagnosis is not None and diagnosis.selection:
            B.append(_table(["effect", "joints", "score in context", "removes per joint (Nm, held out)",
                             "channel"],
                            [[s.effect, s.joints, f"{s.score:.1f}", fmt(np.round(s.contribution, 3).tolist(), 3),
                              s.channel] for s in diagnosis.selection]))
    rows = fit_params(fit) if fit is not None else (selected_params(diagnosis) if diagnosis is not None else [])
    B += ["<h2>Parameters</h2>", _params_html(rows)]
    objs = [(s.effect, s) for s in diagnosis.selection] if diagnosis is not None else []
    if fit is not None:
        objs.append(("fit", fit))
    B.append(_extras_html(objs, diagnosis))
    if diagnosis is not None:
        B += ["<h2>Ranking: each effect alone on the baseline residual</h2>",
              "<p class='muted'>score: held-out evidence (information criterion with the effective sample size); "
              "an effect is significant when its score exceeds the threshold and it removes an error of practical "
              "size.</p>", _ranking_html(diagnosis)]
        u = diagnosis.unexplained
        B.append("<h2>What stays unexplained</h2>")
        if u is None:
            B.append("<p class='muted'>Not tested (no selection).</p>")
        else:
            B.append(f"<p><b>Explained: {'yes' if u.explained else 'NO'}</b>. {_esc(' '.join(u.text))}</p>")
            if u.findings:
                B.append(_table(["joint", "follows", "removes (Nm RMS)", "score", "detail"],
                                [[f.joint, f.group, fmt(f.removed_rms, 3), fmt(f.score, 4), f.detail]
                                 for f in u.findings]))
        if diagnosis.notes:
            B.append("<ul>" + "".join(f"<li>{_esc(n)}</li>" for n in diagnosis.notes) + "</ul>")
    a = diagnosis.assumptions if diagnosis is not None else (fit.assumptions if fit is not None
                                                               else res.assumptions())
    B += ["<h2>Assumptions</h2>", _table(["assumption", "value"],
                                         [[k, json.dumps(v, default=str) if not isinstance(v, str) else v]
                                          for k, v in a.items()])]
    B.append("<h2>Replay in the simulator</h2>")
    if res.replay is not None:
        rp = res.replay
        B.append(f"<p>Mode <b>{_esc(rp.mode)}</b>" + (f"; {_esc(rp.diverged)}" if rp.diverged else "")
                 + f". RMSE_q {fmt(np.round(rp.rmse_q * 1e3, 3).tolist(), 3)} mrad, RMSE_tau "
                 f"{fmt(np.round(rp.rmse_tau, 3).tolist(), 3)} Nm.</p>")
        known = {"mode", "rmse_q", "rmse_tau", "rmse_q_total", "rmse_tau_total", "diverged"}
        more = {k: v for k, v in rp.to_dict().items() if k not in known and v not in (None, [], {})}
        if more:  # what newer replays say about themselves (e.g. why a mode was not available)
            B.append(_table(["replay", "value"], [[k, v if isinstance(v, str) else json.dumps(v, default=str)]
                                                  for k, v in more.items()]))
        B.append(divs["replay"])
    else:
        B.append("<p class='muted'>No replay in this run (diagnose and fit compare by inverse dynamics; run "
                 f"<code>franka-vs compare {_esc(src)} --report DIR</code> for the replay).</p>")
    B.append(f"<p>Next: <code>{_esc(next_command(src, diagnosis, fit, model_file))}</code></p>")
    B.append(f'<script type="application/json" id="franka-vs-plots">{json.dumps(sorted(R.roots))}</script>')
    B.append("</body></html>")
    path.write_text("\n".join(B), encoding="utf-8")
    return path


__all__ = ["html_report"]
