"""The Markdown report of a comparison, a diagnosis and a fit, with its PNG figures
(:mod:`~franka_vs_gym.validation.report.figures`)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.validation.compare import VELOCITY_REGIMES
from franka_vs_gym.validation.report.content import (
    fit_params,
    next_command,
    ranking_status,
    selected_params,
    value_text,
)
from franka_vs_gym.validation.report.figures import compare_figures, plot_before_after, plot_unexplained
from franka_vs_gym.validation.results import CompareResult, Diagnosis, FitResult


def _why_not(d: Diagnosis) -> dict[str, str]:
    """The rejection note of each effect (``notes`` read "<effect> not selected: <why>")."""
    out = {}
    for n in d.notes:
        name, sep, why = n.partition(" not selected: ")
        if sep:
            out[name] = why
    return out


def _diagnosis_section(d: Diagnosis, out: Path) -> list[str]:
    L = ["## Diagnosis", "", f"Verdict: **{d.verdict}**; selected (fitted together, in context): "
         + (", ".join(f"{s.effect} (joints {s.joints})" for s in d.selection) or "nothing"), ""]
    if d.selection:
        L += ["| selected effect | joints | score in context | removes per joint (Nm, held out) |",
              "|---|---|---|---|"]
        for s in d.selection:
            L.append(f"| {s.effect} | {s.joints} | {s.score:.1f} | {np.round(s.contribution, 3).tolist()} |")
        L += ["", "| effect | parameter | value |", "|---|---|---|"]
        L += [f"| {r.effect} | {r.name} | {value_text(r)} |" for r in selected_params(d)]
        L.append("")
    if d.unexplained is not None:
        L += [f"Explained: **{d.unexplained.explained}**. " + " ".join(d.unexplained.text), ""]
        p = plot_unexplained(d, out / "unexplained.png")
        if p is not None:
            L += [f"![unexplained residual]({p.name})", ""]
    changes, amb = getattr(d, "changes", []), getattr(d, "ambiguous", [])
    if changes or amb:
        L += [f"- {c.text()}" for c in changes] + [f"- {a.text()}" for a in amb] + [""]
    if d.notes:
        L += ["Notes:", ""] + [f"- {n}" for n in d.notes] + [""]
    why = _why_not(d)
    L += ["Each effect alone on the baseline residual:", "",
          "| rank | effect | joints | score | status | held-out RMSE after (Nm) | problems, reason not selected |",
          "|---|---|---|---|---|---|---|"]
    for i, c in enumerate(d.ranking):
        reasons = "; ".join(list(c.problems) + ([why[c.effect]] if c.effect in why else []))
        state = "selected" if c.effect in d.selected else ranking_status(c, bool(d.selection))
        L.append(f"| {i + 1} | {c.effect} | {c.joints} | {c.score:.1f} | {state} | "
                 f"{np.round(c.rmse_tau_after, 3).tolist()} | {reasons} |")
    L += ["", "Assumptions: `" + json.dumps(d.assumptions) + "`", ""]
    return L


def _row(values, fmt="{:.3f}") -> str:
    return " | ".join(fmt.format(v) for v in values)


def markdown_report(res: CompareResult, outdir: str | os.PathLike, diagnosis: Diagnosis | None = None,
                    fit: FitResult | None = None, published: dict[str, Any] | None = None,
                    overwrite: bool = False) -> Path:
    """Write ``report.md`` and its figures into ``outdir``. Refuses to overwrite an existing report unless
    ``overwrite``. Returns the report path."""
    out = Path(outdir)
    md = out / "report.md"
    if md.exists() and not overwrite:
        raise FileExistsError(f"{md} exists; choose another folder or pass overwrite=True (--force)")
    figs = compare_figures(res, out)
    L = [f"# Model vs measurement: {res.data.log.source or 'log'}", ""]
    rep = res.data.report
    L += [f"{rep.rows_in} rows in; {rep.stale_rows} stale (repeated) rows and {rep.repeated_timestamps} repeated "
          f"timestamps dropped; raw time step {rep.dt_min * 1e3:.2f} / {rep.dt_median * 1e3:.2f} / "
          f"{rep.dt_max * 1e3:.2f} ms (min / median / max); resampled at {rep.settings['rate']:.0f} Hz, zero-phase "
          f"Butterworth order {rep.settings['order']} at {rep.settings['cutoff']} Hz; {res.data.n} samples used.", ""]
    L += ["## Inverse-dynamics residual per joint (Nm)", "",
          "| | " + " | ".join(f"joint {j}" for j in range(7)) + " | total |",
          "|---" * 9 + "|",
          f"| RMSE | {_row(res.rmse_tau)} | {res.rmse_tau_total:.3f} |",
          f"| mean (bias) | {_row(res.mean_tau)} | |",
          f"| noise floor | {_row(res.noise_floor)} | |"]
    if res.replay is not None:
        rp = res.replay
        L += [f"| replay RMSE_tau ({rp.mode}) | {_row(rp.rmse_tau)} | |",
              f"| replay RMSE_q (mrad) | {_row(rp.rmse_q * 1e3)} | |"]
        if getattr(rp, "fallback_from", None) or getattr(rp, "stop", None):
            L += ["", f"Replay: {rp.status()}.", ""]
    L += ["", "## Where the error concentrates", "",
          "| joint | RMSE | worst window (s) | " + " | ".join(r[2] for r in VELOCITY_REGIMES) + " |",
          "|---" * 6 + "|"]
    for row in res.concentration:
        w = row["worst_window"]
        cells = [f"{r['error_share'] * 100:.0f}% of error, {r['samples'] * 100:.0f}% of samples"
                 for r in row["regimes"]]
        L.append(f"| {row['joint']} | {row['rmse']:.3f} | {w['t0']:.1f}-{w['t1']:.1f} ({w['rmse']:.3f}) | "
                 + " | ".join(cells) + " |")
    L += ["", "## Figures", ""]
    for name, p in figs.items():
        L += [f"![residual vs {name}]({p.name})", ""]
    if diagnosis is not None:
        L += _diagnosis_section(diagnosis, out)
    if fit is not None:
        p = plot_before_after(fit, out / "before_after.png", published)
        L += ["## Fit: before and after", "", f"Effects added: {', '.join(fit.effects) or 'none'}", "",
              "| | " + " | ".join(f"joint {j}" for j in range(7)) + " |", "|---" * 8 + "|",
              f"| before | {_row(fit.rmse_before)} |", f"| after | {_row(fit.rmse_after)} |",
              f"| noise floor | {_row(fit.noise_floor)} |"]
        for name, vals in (published or {}).items():
            L.append(f"| {name} | {_row(vals)} |")
        L += ["", f"![before and after]({p.name})", "", "Fitted parameters:", "",
              "| effect | parameter | value | note |", "|---|---|---|---|"]
        L += [f"| {r.effect} | {r.name} | {value_text(r)} | {r.note} |" for r in fit_params(fit)]
        L.append("")
    L += ["## Next", "", "```", next_command(res.data.log.source, diagnosis, fit), "```", ""]
    md.write_text("\n".join(L))
    return md


__all__ = ["markdown_report"]
