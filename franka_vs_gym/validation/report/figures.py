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

from franka_vs_gym.validation.report.content import binned_mean, envelope, finding_views
from franka_vs_gym.validation.results import CompareResult, Diagnosis, FitResult

# Cost: text layout (tick labels, titles) dominates a grid figure, not the data. Figures are therefore made on the
# Agg canvas directly (no pyplot state, nothing to close), with fixed margins instead of tight_layout (which lays every
# text out again), at most 5 ticks per axis, long traces decimated to a min/max envelope of about two points per pixel
# column of their panel (what Agg could draw of them anyway), and one grid reused for the three scatter figures.
DPI = 90
SCATTER_POINTS = 4000  # per panel


def _figure(size):
    """A figure on its own Agg canvas (matplotlib imported here, when a figure is first made)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def _few_ticks(ax) -> None:
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(5, steps=[1, 2, 2.5, 5, 10]))
    ax.yaxis.set_major_locator(MaxNLocator(5, steps=[1, 2, 2.5, 5, 10]))
    ax.tick_params(labelsize=7)


def _lowpass_residual(res: CompareResult) -> np.ndarray:
    return res.data.tau_filt - res.evaluation.predicted


def _grid(title: str, sharex: bool = False, size=(14, 8.5)):
    """Seven joint panels on a 2 x 4 grid (fixed margins); the eighth cell is left for a legend."""
    fig = _figure(size)
    axes = fig.subplots(2, 4, sharex=sharex)
    fig.subplots_adjust(left=0.05, right=0.99, bottom=0.075, top=0.9, wspace=0.26, hspace=0.32)
    fig.suptitle(title)
    axes.flat[7].axis("off")
    if sharex:  # joint 3 has no panel below it: it keeps its tick labels
        axes.flat[3].xaxis.set_tick_params(labelbottom=True)
    for ax in axes.flat[:7]:
        _few_ticks(ax)
    return fig, list(axes.flat[:7]), axes.flat[7]


def _pixels(fig, ax) -> int:
    """Width of a panel in pixels."""
    return max(50, int(ax.get_position().width * fig.get_figwidth() * DPI))


def _legend_cell(cell, ax) -> None:
    h, lab = ax.get_legend_handles_labels()
    if h:
        cell.legend(h, lab, loc="center", fontsize=9, frameon=False)


def plot_residual_time(res: CompareResult, path: Path) -> Path:
    t = res.data.time
    rf = _lowpass_residual(res)
    fig, axes, cell = _grid("Inverse-dynamics residual tau_J - tau_model over time", sharex=True)
    npx = 2 * _pixels(fig, axes[0])  # a min and a max per pixel column
    for j, ax in enumerate(axes):
        ax.plot(*envelope(t, res.residual[:, j], npx), color="0.75", lw=0.5, label="raw")  # extremes stay
        ax.plot(*envelope(t, rf[:, j], npx), color="C0", lw=1.0, label="low-passed")
        ax.axhspan(-res.noise_floor[j], res.noise_floor[j], color="C2", alpha=0.15, label="+-noise floor")
        ax.set_title(f"joint {j}: RMSE {res.rmse_tau[j]:.3f} Nm", fontsize=9)
        if j % 4 == 0:
            ax.set_ylabel("residual (Nm)", fontsize=8)
        if j >= 3:
            ax.set_xlabel("time (s)", fontsize=8)
    _legend_cell(cell, axes[0])
    fig.savefig(path)
    return path


class _ScatterGrid:
    """The low-passed residual against one variable per joint on a 2 x 4 grid; drawn again for the next variable
    (the axes, ticks and texts are reused, only data and labels change)."""

    def __init__(self) -> None:
        self.fig, self.axes, _ = _grid("", size=(14, 6.5))
        self.fig.subplots_adjust(bottom=0.09, top=0.88)
        self.dots = [ax.plot([], [], ".", ms=1.5, alpha=0.4, color="C0")[0] for ax in self.axes]
        for j, ax in enumerate(self.axes):
            ax.axhline(0, color="k", lw=0.5)
            ax.set_title(f"joint {j}", fontsize=9)
            if j % 4 == 0:
                ax.set_ylabel("residual (Nm)", fontsize=8)

    def draw(self, res: CompareResult, x: np.ndarray, xlabel: str, title: str, path: Path,
             per_joint_x: bool = True) -> Path:
        rf = _lowpass_residual(res)
        step = max(1, len(rf) // SCATTER_POINTS)
        self.fig.suptitle(title)
        for j, (ax, dots) in enumerate(zip(self.axes, self.dots, strict=True)):
            xj = x[::step, j] if per_joint_x else x[::step]
            dots.set_data(xj, rf[::step, j])
            ax.relim()
            ax.autoscale_view()
            ax.set_xlabel(xlabel, fontsize=8)
        self.fig.savefig(path)
        return path


def plot_residual_against(res: CompareResult, x: np.ndarray, xlabel: str, title: str, path: Path,
                          per_joint_x: bool = True) -> Path:
    return _ScatterGrid().draw(res, x, xlabel, title, path, per_joint_x)


def plot_before_after(fit: FitResult, path: Path, published: dict[str, Any] | None = None) -> Path:
    fig = _figure((8, 4))
    ax = fig.add_subplot()
    fig.subplots_adjust(left=0.09, right=0.98, bottom=0.13, top=0.9)
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
    fig.savefig(path)
    return path


def compare_figures(res: CompareResult, outdir: Path) -> dict[str, Path]:
    """Write the four residual figures into ``outdir``; returns name -> path."""
    outdir.mkdir(parents=True, exist_ok=True)
    out = {"time": plot_residual_time(res, outdir / "residual_time.png")}
    grid = _ScatterGrid()
    out["velocity"] = grid.draw(res, res.data.dq, "dq (rad/s)", "Residual (low-passed) vs joint velocity",
                                outdir / "residual_velocity.png")
    out["acceleration"] = grid.draw(res, res.data.ddq, "ddq (rad/s^2)", "Residual (low-passed) vs joint acceleration",
                                    outdir / "residual_acceleration.png")
    out["gravity"] = grid.draw(res, res.evaluation.gravity, "model gravity torque g(q) (Nm)",
                               "Residual (low-passed) vs gravity torque", outdir / "residual_gravity.png")
    return out


def plot_unexplained(diagnosis: Diagnosis, path: Path) -> Path | None:
    """Residual of the selected model against what it follows, one panel per joint with structure left, on a grid;
    a periodic finding is drawn against the phase of its period (the period is visible as one cycle)."""
    views = finding_views(diagnosis)
    if not views:
        return None
    ncol = min(3, len(views))
    nrow = int(np.ceil(len(views) / ncol))
    fig = _figure((4.6 * ncol, 3.6 * nrow))
    axes = fig.subplots(nrow, ncol, squeeze=False)
    fig.subplots_adjust(left=0.08 if ncol > 1 else 0.16, right=0.98, bottom=0.6 / (3.6 * nrow) + 0.04,
                        top=1 - 0.75 / (3.6 * nrow), wspace=0.3, hspace=0.55)
    fig.suptitle("What the residual of the selected effects still follows")
    for ax in axes.flat[len(views):]:
        ax.axis("off")
    for ax, v in zip(axes.flat, views, strict=False):
        _few_ticks(ax)
        k = max(1, len(v.x) // 3000)
        ax.plot(v.x[::k], v.r[::k], ".", ms=1.5, alpha=0.35, color="C0", label="residual")
        xm, rm = binned_mean(v.x, v.r)
        ax.plot(xm, rm, "-", color="C3", lw=1.8, label="binned mean")
        ax.axhspan(-v.noise, v.noise, color="0.85", zorder=0, label="+-noise floor")
        ax.set_xlabel(v.xlabel, fontsize=8)
        ax.set_ylabel(f"residual joint {v.joint} (Nm)", fontsize=8)
        head, _, detail = v.title.partition(" (")
        ax.set_title(head + ("\n(" + detail if detail else ""), fontsize=9)
    axes.flat[0].legend(loc="upper right", fontsize=7)  # a fixed place: "best" searches over every point
    fig.savefig(path, dpi=100)
    return path


__all__ = ["compare_figures", "plot_before_after", "plot_residual_against", "plot_residual_time", "plot_unexplained"]
