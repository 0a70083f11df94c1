"""The page's text panels (HTML for Bokeh ``Div``\\ s): the held-out error, the enabled set's fitted values with the
parameters at their bounds, the diagnosis as ``franka-vs diagnose`` prints it (the report's own lines,
:mod:`~franka_vs_gym.validation.report.content`), and a saved fit's values with their intervals."""

from __future__ import annotations

import html
from pathlib import Path

import numpy as np

from franka_vs_gym.validation.app import session as S
from franka_vs_gym.validation.results import rmse

WARN = "color:#b00020"


def _nums(a, nd: int = 3) -> str:
    return "".join(f"<td style='text-align:right;padding:0 6px'>{x:.{nd}f}</td>" for x in a)


def rmse_html(op: S.Opened, base: S.Refit, cur: S.Refit) -> str:
    """The held-out RMSE per joint and in total, baseline and with the enabled set, beside the noise floor, and
    fit % (the total is in ``data-total`` for scripts)."""
    tb, tc = float(rmse(base.rmse_heldout)), float(rmse(cur.rmse_heldout))
    head = "".join(f"<th style='padding:0 6px'>joint {j}</th>" for j in range(7))
    on = ", ".join(f"{k}" + (f" ({','.join(map(str, v))})" if v is not None else "") for k, v in cur.enabled.items())
    return (f"<div data-total='{tc:.6f}' data-baseline='{tb:.6f}'>held-out part ({len(op.test)} samples, "
            f"{op.time[-1] - op.split_time:.1f} s): total RMSE <b>{tb:.3f} &rarr; {tc:.3f} Nm</b> with "
            f"{html.escape(on) or 'no effect'} (refit in {1000 * cur.seconds:.0f} ms)</div>"
            f"<table style='font-size:90%'><tr><th></th>{head}</tr>"
            f"<tr><td>baseline (Nm)</td>{_nums(base.rmse_heldout)}</tr>"
            f"<tr><td>enabled (Nm)</td>{_nums(cur.rmse_heldout)}</tr>"
            f"<tr><td>noise floor (Nm)</td>{_nums(op.noise)}</tr>"
            f"<tr><td>fit part (Nm)</td>{_nums(cur.rmse_fit)}</tr>"
            f"<tr><td>fit % held out</td>{_nums(cur.fit_percent, 1)}</tr></table>")


def _value(v) -> str:
    a = np.asarray(v, dtype=object)
    if a.ndim == 0:
        return f"{float(v):.4g}" if isinstance(v, (int, float)) else html.escape(str(v))
    flat = a.ravel().tolist()
    return "[" + " ".join("-" if x is None else f"{float(x):.4g}" for x in flat) + "]"


def params_html(cur: S.Refit, ci: dict | None = None) -> str:
    """The enabled set's fitted values (fit part) with their 95 % intervals once computed (``ci``: effect -> the
    intervals, or ``{"_error": line}``) and, in red beside them, the parameters at a bound."""
    if not cur.params:
        return "<i>no effect enabled: the residual is the baseline model's</i>"
    note = ("95 % intervals computing..." if ci is None else
            f"intervals not computed: {html.escape(ci['_error'])}" if "_error" in ci else "with 95 % intervals")
    out = [f"<b>fitted values of the enabled set</b> (on the fit part; {note}):<ul style='margin:2px'>"]
    for name, p in cur.params.items():
        c = (ci or {}).get(name) or {}
        vals = "; ".join(f"{html.escape(k)} {_value(v)}" + (f" (95% {_value(c[k])})" if c.get(k) is not None else "")
                         for k, v in p.items() if k != "joints")
        warn = S.bound_warnings(name, p, c) if c else [w for w in cur.at_bound if w.startswith(name + " ")]
        out.append(f"<li><b>{html.escape(name)}</b> (joints {p.get('joints')}): {vals}"
                   + "".join(f"<br><span style='{WARN}'>&#9888; {html.escape(w)}</span>" for w in warn) + "</li>")
    return "".join(out) + "</ul>"


def candidates_html(d) -> str:
    """The diagnosis as ``diagnose`` prints it (verdict, the selected set's values with intervals, changes,
    ambiguities, explained), the selected parameters at their bounds beside their intervals, and the notes."""
    from franka_vs_gym.validation.report.content import verdict_lines

    lines = [html.escape(x) for x in verdict_lines(d)]
    for s in d.selection:
        for w in S.bound_warnings(s.effect, {**s.params, "joints": s.joints}, s.params_ci95):
            lines.append(f"<span style='{WARN}'>&#9888; {html.escape(w)}</span>")
    sel = ""
    if d.rmse_tau_selected is not None and d.selection:
        sel = (f"<br>torque RMSE (Nm) {np.round(d.rmse_tau, 3).tolist()} &rarr; "
               f"{np.round(d.rmse_tau_selected, 3).tolist()} with the selected set (5-fold held out)")
    amb = "ambiguous: " + ("; ".join(" or ".join(a.candidates) for a in d.ambiguous) if d.ambiguous else "none")
    notes = "".join(f"<li>{html.escape(n)}</li>" for n in d.notes[:12])
    return ("<div style='font-family:monospace;font-size:90%;white-space:pre-wrap'>" + "<br>".join(lines)
            + f"<br>{html.escape(amb)}" + sel + "</div>"
            + (f"<details><summary>notes ({len(d.notes)})</summary><ul>{notes}</ul></details>" if d.notes else ""))


def fit_html(res) -> str:
    """A saved fit's values with their 95 % intervals (as ``fit`` prints them) and the parameters at a bound."""
    from franka_vs_gym.validation.report.content import fit_lines

    lines = [html.escape(x) for x in fit_lines(res)]
    for name, p in res.params.items():
        for w in S.bound_warnings(name, p, res.params_ci95.get(name)):
            lines.append(f"<span style='{WARN}'>&#9888; {html.escape(w)}</span>")
    for name, why in res.notes.items():
        lines.append(html.escape(f"{name}: {why}"))
    return ("<div style='font-family:monospace;font-size:90%;white-space:pre-wrap'><b>saved fit</b> (all samples, "
            "with the effects' refinements, as franka-vs fit):<br>" + "<br>".join(lines) + "</div>")


def free_name(path: str) -> str:
    """``path``, or the first ``path-2``, ``path-3``... that does not exist (a new name: nothing is overwritten)."""
    p = Path(path)
    if not p.exists():
        return str(p)
    for i in range(2, 1000):
        q = p.with_name(f"{p.stem}-{i}{p.suffix}")
        if not q.exists():
            return str(q)
    return str(p)


def short(params: dict, n: int = 160) -> str:
    """Fitted values on one line of at most ``n`` characters (the ranking table's column)."""
    parts = []
    for k, v in params.items():
        if k == "joints":
            continue
        a = np.asarray(v, dtype=object)
        if a.ndim == 0:
            parts.append(f"{k} {v:.4g}" if isinstance(v, float) else f"{k} {v}")
        else:
            flat = [x for x in a.ravel().tolist() if x is not None]
            parts.append(f"{k} [" + " ".join(f"{float(x):.3g}" for x in flat[:7]) + (" ..." if len(flat) > 7 else "")
                         + "]")
    s = "; ".join(parts)
    return s if len(s) <= n else s[: n - 3] + "..."


__all__ = ["candidates_html", "fit_html", "free_name", "params_html", "rmse_html", "short"]
