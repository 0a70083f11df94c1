"""Reports of a comparison, a diagnosis and a fit.

- :mod:`.html`: ``report.html``, one self-contained interactive file (Bokeh, its JavaScript inlined once);
- :mod:`.markdown`: ``report.md`` with the PNG figures of :mod:`.figures`;
- :mod:`.mcap`: the run as an MCAP log (measurement, model, residual, effects, findings on one timeline);
- :mod:`.content`: what all of them show, read from the workbench's results (nothing is computed again).
"""

from franka_vs_gym.validation.report.figures import (
    compare_figures,
    plot_before_after,
    plot_residual_against,
    plot_residual_time,
    plot_unexplained,
)
from franka_vs_gym.validation.report.markdown import markdown_report

__all__ = ["compare_figures", "html_report", "markdown_report", "plot_before_after", "plot_residual_against",
           "plot_residual_time", "plot_unexplained", "write_mcap"]


def __getattr__(name: str):
    # the HTML and MCAP writers import their libraries (bokeh, mcap) only when used
    if name == "html_report":
        from franka_vs_gym.validation.report.html import html_report

        return html_report
    if name == "write_mcap":
        from franka_vs_gym.validation.report.mcap import write_mcap

        return write_mcap
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
