"""The report's figures as PNG files (matplotlib, Agg backend), for papers and quick looks; each a grid of one
panel per joint, readable at a glance.

- ``residual_time.png``: residual over time, raw (light) and low-passed (dark), with the +-noise-floor band;
- ``residual_velocity.png``: low-passed residual against joint velocity (friction signatures: a line = viscous, a
  step at 0 = Coulomb, a rounded step = sigmoid/Stribeck);
- ``residual_acceleration.png``: against joint acceleration (armature, inertia errors);
- ``residual_gravity.png``: against the model's gravity torque (payload, tilt, mass errors);
- ``unexplained.png``: what the residual of the selected effects still follows, per joint (a periodic finding
  against the phase of its period);
- ``before_after.png``: per-joint RMSE before and after the fit, with the noise floor (and published values if
  given).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.validation.compare import CompareResult
from franka_vs_gym.validation.diagnose import Diagnosis, FitResult
from franka_vs_gym.validation.report.content import binned_mean, finding_views


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _lowpass_residual(res: CompareResult) -> np.ndarray:
    return res.data.tau_filt - res.evaluation.predicted


def _grid(plt, title: str, sharex: bool = False, size=(14, 8.5)):
    """Seven joint panels on a 2 x 4 grid; the eighth cell is left for a legend."""
    fig, axes = plt.subplots(2, 4, figsize=size, sharex=sharex)
    fig.suptitle(title)
    axes.flat[7].axis("off")
    return fig, list(axes.flat[:7]), axes.flat[7]


def _legend_cell(cell, ax) -> None:
    h, lab = ax.get_legend_handles_labels()
    if h:
        cell.legend(h, lab, loc="center", fontsize=9, frameon=False)


def plot_residual_time(res: CompareResult, path: Path) -> Path:
    plt = _plt()
    t = res.data.time
    rf = _lowpass_residual(res)
    fig, axes, cell = _grid(plt, "Inverse-dynamics residual tau_J - tau_model over time", sharex=True)
    step = max(1, len(t) // 6000)
    for j, ax in enumerate(axes):
        ax.plot(t[::step], res.residual[::step, j], color="0.75", lw=0.5, label="raw")
        ax.plot(t[::step], rf[::step, j], color="C0", lw=1.0, label="low-passed")
        ax.axhspan(-res.noise_floor[j], res.noise_floor[j], color="C2", alpha=0.15, label="+-noise floor")
        ax.set_title(f"joint {j}: RMSE {res.rmse_tau[j]:.3f} Nm", fontsize=9)
        if j % 4 == 0:
            ax.set_ylabel("residual (Nm)", fontsize=8)
        if j >= 3:
            ax.set_xlabel("time (s)", fontsize=8)
        ax.tick_params(labelsize=7)
    _legend_cell(cell, axes[0])
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_residual_against(res: CompareResult, x: np.ndarray, xlabel: str, title: str, path: Path,
                          per_joint_x: bool = True) -> Path:
    plt = _plt()
    rf = _lowpass_residual(res)
    fig, axes = plt.subplots(2, 4, figsize=(14, 6.5))
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
    """Residual of the selected model against what it follows, one panel per joint with structure left, on a grid;
    a periodic finding is drawn against the phase of its period (the period is visible as one cycle)."""
    views = finding_views(diagnosis)
    if not views:
        return None
    plt = _plt()
    ncol = min(3, len(views))
    nrow = int(np.ceil(len(views) / ncol))
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.6 * ncol, 3.6 * nrow), squeeze=False)
    fig.suptitle("What the residual of the selected effects still follows")
    for ax in axes.flat[len(views):]:
        ax.axis("off")
    for ax, v in zip(axes.flat, views, strict=False):
        k = max(1, len(v.x) // 3000)
        ax.plot(v.x[::k], v.r[::k], ".", ms=1.5, alpha=0.35, color="C0", label="residual")
        xm, rm = binned_mean(v.x, v.r)
        ax.plot(xm, rm, "-", color="C3", lw=1.8, label="binned mean")
        ax.axhspan(-v.noise, v.noise, color="0.85", zorder=0, label="+-noise floor")
        ax.set_xlabel(v.xlabel, fontsize=8)
        ax.set_ylabel(f"residual joint {v.joint} (Nm)", fontsize=8)
        head, _, detail = v.title.partition(" (")
        ax.set_title(head + ("\n(" + detail if detail else ""), fontsize=9)
        ax.tick_params(labelsize=7)
    axes.flat[0].legend(loc="best", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


__all__ = ["compare_figures", "plot_before_after", "plot_residual_against", "plot_residual_time", "plot_unexplained"]
