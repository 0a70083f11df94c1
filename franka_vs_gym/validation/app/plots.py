"""The workbench page's figures and their data sources: the residual over time, against velocity and against
position (with the noise bands, the held-out part and the cursor), the held-out RMSE per joint and the fit % per model
variant. They are attributes of the :class:`~.page.Page` that draws into them."""

from __future__ import annotations

from typing import Any

from bokeh.models import BoxAnnotation, ColumnDataSource, Div, FactorRange, Span
from bokeh.plotting import figure

TOOLS = "pan,box_zoom,wheel_zoom,reset,save"


def build_figures(page: Any) -> None:
    """Create the :class:`~.page.Page`'s figures and data sources (``page.src``, ``page.f_time``, ...
    ``page.params_div``)."""
    page.src = ColumnDataSource(dict(t=[], base=[], cur=[], dq=[], q=[]))
    page.ovl_src = ColumnDataSource(dict(xs=[], ys=[], colour=[], label=[]))
    page.f_time = figure(height=260, width=820, title="residual tau_J - model (Nm) over time", tools=TOOLS,
                         x_axis_label="time (s)", y_axis_label="Nm", name="f_time")
    page.f_time.multi_line("xs", "ys", color="colour", source=page.ovl_src, alpha=0.7, legend_field="label")
    page.f_time.line("t", "base", source=page.src, color="#aaaaaa", legend_label="baseline model")
    page.f_time.line("t", "cur", source=page.src, color="#1f77b4", legend_label="with the enabled effects")
    page.f_time.legend.location = "top_left"
    page.f_time.legend.background_fill_alpha = 0.6
    page.f_time.on_event("tap", lambda ev: page._move_cursor(ev.x, set_slider=True))
    page.f_dq = figure(height=260, width=400, title="residual against velocity", tools=TOOLS,
                       x_axis_label="dq (rad/s)", y_axis_label="Nm", name="f_dq")
    page.f_q = figure(height=260, width=400, title="residual against position", tools=TOOLS,
                      x_axis_label="q (rad)", y_axis_label="Nm", name="f_q")
    for f, x in ((page.f_dq, "dq"), (page.f_q, "q")):
        f.scatter(x, "base", source=page.src, size=2, color="#bbbbbb", alpha=0.5)
        f.scatter(x, "cur", source=page.src, size=2, color="#1f77b4", alpha=0.5)
    page.bands = [BoxAnnotation(bottom=-1, top=1, fill_color="#2ca02c", fill_alpha=0.12) for _ in range(3)]
    for f, b in zip((page.f_time, page.f_dq, page.f_q), page.bands, strict=True):
        f.add_layout(b)
    page.heldout_box = BoxAnnotation(left=0, fill_color="#ff7f0e", fill_alpha=0.06)
    page.f_time.add_layout(page.heldout_box)
    page.span = Span(location=0, dimension="height", line_color="#d62728", line_width=2)
    page.f_time.add_layout(page.span)
    page.arm_div = Div(text="", width=430, height=400, name="arm")

    page.rmse_src = ColumnDataSource(dict(x=[], v=[], colour=[], kind=[]))
    page.f_rmse = figure(height=250, width=560, tools="save",
                         title="held-out RMSE per joint (Nm): grey baseline, blue enabled, black dash noise floor",
                         x_range=FactorRange(*[(f"joint {j}", k) for j in range(7)
                                               for k in ("baseline", "enabled")]),
                         name="f_rmse")
    page.f_rmse.vbar(x="x", top="v", width=0.8, color="colour", source=page.rmse_src)
    page.noise_src = ColumnDataSource(dict(x=[], v=[]))
    page.f_rmse.scatter("x", "v", source=page.noise_src, marker="dash", size=22, color="black", line_width=2)
    page.f_rmse.xaxis.major_label_text_font_size = "0pt"  # the joints (group labels) only
    page.f_rmse.xaxis.group_label_orientation = 0.0
    page.fitp_src = ColumnDataSource(dict(x=[], v=[], colour=[], variant=[]))
    page.f_fitp = figure(height=300, width=780, title="fit % per joint and model variant (100 = perfect; held out)",
                         tools="save", x_range=FactorRange(factors=[("0", "baseline")]), name="f_fitp")
    page.f_fitp.vbar(x="x", top="v", width=0.8, color="colour", source=page.fitp_src, legend_field="variant")
    page.f_fitp.xaxis.major_label_text_font_size = "0pt"  # the joints (group labels); variants in the legend
    page.f_fitp.legend.label_text_font_size = "8pt"
    page.f_fitp.add_layout(page.f_fitp.legend[0], "right")
    page.rmse_div = Div(text="", width=1200, height=130, name="heldout")
    page.params_div = Div(text="", width=1250, height=110, name="params", styles={"overflow-y": "auto"})


__all__ = ["TOOLS", "build_figures"]
