"""Figures and a Markdown report of a comparison, a diagnosis and a fit (matplotlib, Agg backend).

Figures (PNG, one panel per joint):

- ``residual_time.png``: residual over time, raw (light) and low-passed (dark), with the +-noise-floor band;
- ``residual_velocity.png``: low-passed residual against joint velocity (friction signatures: a line = viscous, a
  step at 0 = Coulomb, a rounded step = sigmoid/Stribeck);
- ``residual_acceleration.png``: against joint acceleration (armature, inertia errors);
- ``residual_gravity.png``: against the model's gravity torque (payload, tilt, mass errors);
- ``before_after.png``: per-joint RMSE before and after the fit, with the noise floor (and published values if
  given).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.validation.compare import VELOCITY_REGIMES, CompareResult
from franka_vs_gym.validation.diagnose import Diagnosis, FitResult


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _lowpass_residual(res: CompareResult) -> np.ndarray:
    return res.data.tau_filt - res.evaluation.predicted


def _panels(plt, title: str):
    fig, axes = plt.subplots(7, 1, figsize=(9, 13), sharex=True)
    fig.suptitle(title)
    return fig, axes


def plot_residual_time(res: CompareResult, path: Path) -> Path:
    plt = _plt()
    t = res.data.time
    rf = _lowpass_residual(res)
    fig, axes = _panels(plt, "Inverse-dynamics residual tau_J - tau_model over time")
    step = max(1, len(t) // 8000)
    for j, ax in enumerate(axes):
        ax.plot(t[::step], res.residual[::step, j], color="0.75", lw=0.5, label="raw")
        ax.plot(t[::step], rf[::step, j], color="C0", lw=1.0, label="low-passed")
        ax.axhspan(-res.noise_floor[j], res.noise_floor[j], color="C2", alpha=0.15, label="+-noise floor")
        ax.set_ylabel(f"joint {j}\nNm")
        ax.text(0.99, 0.9, f"RMSE {res.rmse_tau[j]:.3f} Nm", transform=ax.transAxes, ha="right", va="top",
                fontsize=8)
    axes[0].legend(loc="upper left", fontsize=7, ncol=3)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_residual_against(res: CompareResult, x: np.ndarray, xlabel: str, title: str, path: Path,
                          per_joint_x: bool = True) -> Path:
    plt = _plt()
    rf = _lowpass_residual(res)
    fig, axes = plt.subplots(2, 4, figsize=(13, 6))
    fig.suptitle(title)
    step = max(1, len(rf) // 4000)
    for j in range(7):
        ax = axes.flat[j]
        xj = x[::step, j] if per_joint_x else x[::step]
        ax.scatter(xj, rf[::step, j], s=1, alpha=0.4, color="C0")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_title(f"joint {j}", fontsize=9)
        ax.set_xlabel(xlabel, fontsize=8)
        if j % 4 == 0:
            ax.set_ylabel("residual (Nm)", fontsize=8)
    axes.flat[7].axis("off")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_before_after(fit: FitResult, path: Path, published: dict[str, Any] | None = None) -> Path:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 4))
    j = np.arange(7)
    w = 0.35
    ax.bar(j - w / 2, fit.rmse_before, w, label="before")
    ax.bar(j + w / 2, fit.rmse_after, w, label="after (" + ", ".join(fit.effects) + ")")
    ax.plot(j, fit.noise_floor, "k_", markersize=20, mew=2, label="noise floor")
    for name, vals in (published or {}).items():
        ax.plot(j, vals, "o", mfc="none", label=name)
    ax.set_xticks(j)
    ax.set_xlabel("joint")
    ax.set_ylabel("torque RMSE (Nm)")
    ax.legend(fontsize=8)
    ax.set_title("Inverse-dynamics residual before and after adding the fitted effects")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def compare_figures(res: CompareResult, outdir: Path) -> dict[str, Path]:
    """Write the four residual figures into ``outdir``; returns name -> path."""
    outdir.mkdir(parents=True, exist_ok=True)
    return {
        "time": plot_residual_time(res, outdir / "residual_time.png"),
        "velocity": plot_residual_against(res, res.data.dq, "dq (rad/s)", "Residual (low-passed) vs joint velocity",
                                          outdir / "residual_velocity.png"),
        "acceleration": plot_residual_against(res, res.data.ddq, "ddq (rad/s^2)",
                                              "Residual (low-passed) vs joint acceleration",
                                              outdir / "residual_acceleration.png"),
        "gravity": plot_residual_against(res, res.evaluation.gravity, "model gravity torque g(q) (Nm)",
                                         "Residual (low-passed) vs gravity torque", outdir / "residual_gravity.png"),
    }


def plot_unexplained(diagnosis: Diagnosis, path: Path) -> Path | None:
    """Residual of the selected model against what it follows, one panel per joint with structure left."""
    u = diagnosis.unexplained
    if u is None or not u.plot_data:
        return None
    plt = _plt()
    joints = sorted(u.plot_data)
    fig, axes = plt.subplots(1, len(joints), figsize=(4.2 * len(joints), 3.4), squeeze=False)
    from franka_vs_gym.validation.structure import FOLLOWS

    for ax, j in zip(axes[0], joints, strict=True):
        group, x, r, nf = u.plot_data[j]
        ax.plot(x, r, ".", ms=1.5, alpha=0.35, color="C0")
        order = np.argsort(x)
        k = max(1, len(x) // 60)
        xs = x[order]
        rs = np.convolve(r[order], np.ones(k) / k, mode="same")
        ax.plot(xs, rs, "-", color="C3", lw=1.5, label="running mean")
        ax.axhspan(-nf[0], nf[0], color="0.85", zorder=0, label="noise floor")
        ax.set_xlabel(FOLLOWS[group])
        ax.set_ylabel(f"residual joint {j} (Nm)")
        ax.set_title(f"joint {j}: unexplained")
    axes[0][0].legend(loc="best", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _diagnosis_section(d: Diagnosis, out: Path) -> list[str]:
    L = ["## Diagnosis", "", f"Verdict: **{d.verdict}**; selected (fitted together, in context): "
         + (", ".join(f"{s.effect} (joints {s.joints})" for s in d.selection) or "nothing"), ""]
    if d.selection:
        L += ["| selected effect | joints | score in context | removes per joint (Nm, held out) |",
              "|---|---|---|---|"]
        for s in d.selection:
            L.append(f"| {s.effect} | {s.joints} | {s.score:.1f} | {np.round(s.contribution, 3).tolist()} |")
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
    L += ["Each effect alone on the baseline residual:", "",
          "| rank | effect | joints | score | significant | plausible | held-out RMSE after (Nm) | problems |",
          "|---|---|---|---|---|---|---|---|"]
    for i, c in enumerate(d.ranking):
        L.append(f"| {i + 1} | {c.effect} | {c.joints} | {c.score:.1f} | {c.significant} | {c.plausible} | "
                 f"{np.round(c.rmse_tau_after, 3).tolist()} | {'; '.join(c.problems)} |")
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
        L += ["", f"![before and after]({p.name})", "", "Fitted parameters:", "", "```",
              json.dumps(fit.params, indent=1), "```", ""]
    md.write_text("\n".join(L))
    return md


__all__ = ["compare_figures", "markdown_report", "plot_before_after", "plot_unexplained", "plot_residual_against",
           "plot_residual_time"]
