"""The workbench page (one Bokeh document per browser tab): it draws what :mod:`.session` computes and sends the
user's actions back. Long jobs go to the shared :class:`~.state.App`'s worker; the page polls it (every
``POLL_MS``) for progress, errors and results. A toggle refits in the page's own callback and redraws at once."""

from __future__ import annotations

import html
import os
import time
from pathlib import Path

import numpy as np
from bokeh.events import DocumentReady
from bokeh.layouts import column, row
from bokeh.models import (
    Button,
    CheckboxButtonGroup,
    ColumnDataSource,
    DataTable,
    Div,
    RadioButtonGroup,
    Select,
    Slider,
    Spinner,
    TableColumn,
    TextInput,
)

from franka_vs_gym.errors import is_user_error, one_line
from franka_vs_gym.validation.app import session as S
from franka_vs_gym.validation.app.arm import RED_AT, ArmView, NoGL
from franka_vs_gym.validation.app.panels import candidates_html, fit_html, free_name, params_html, rmse_html, short
from franka_vs_gym.validation.app.plots import build_figures
from franka_vs_gym.validation.app.state import App

POLL_MS = 250
MAX_POINTS = 3000  # samples drawn per curve (the log decimated by a whole stride for the browser)
OVERLAY_COLOURS = ("#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf")


def _stride(n: int) -> int:
    return max(1, -(-n // MAX_POINTS))


class Page:
    def __init__(self, app: App, doc) -> None:
        self.app, self.doc = app, doc
        self.seen_version = -1
        self.seen_log = -1
        self.touched = False  # the user changed a toggle (the diagnosis' preset is applied only before)
        self.preset_applied = False
        self.current: S.Refit | None = None
        self.baseline: S.Refit | None = None
        self.preset_fit: S.Refit | None = None
        self.arm = app.arm if getattr(app, "arm", None) is not None else ArmView()
        app.arm = self.arm  # one OpenGL context for every tab (all callbacks run on the server's one thread)
        self.toggles: dict[str, CheckboxButtonGroup] = {}
        self.last_toggle_s = 0.0
        self._build()
        doc.add_root(self.root)
        doc.title = "franka-vs workbench"
        self._shown = self._drawn = False
        doc.on_event(DocumentReady, self._on_shown)
        doc.add_periodic_callback(self.poll, POLL_MS)
        self.poll()

    def _on_shown(self, event) -> None:
        """The browser has drawn the document: once it shows the log, the diagnosis may start."""
        self._shown = True
        if self._drawn:
            self.doc.add_timeout_callback(self.app.page_ready.set, 300)

    # ------------------------------------------------------------------ layout
    def _build(self) -> None:
        app = self.app
        self.title = Div(text="<h2 style='margin:4px 0'>franka-vs workbench</h2>", name="title")
        start = app.opened.path if app.opened else ""
        self.path = TextInput(title="log (file or folder)", value=start, width=520, name="path")
        self.open_btn = Button(label="open", button_type="primary", width=80, name="open", align="end")
        self.open_btn.on_click(lambda: self._open(self.path.value))
        self.files = Select(title="files in the log's folder", options=self._folder_files(start or "."), width=420,
                            name="files")
        self.files.on_change("value", lambda a, o, n: self._pick(n))
        # fixed sizes: a change of their text does not lay the whole page out again
        self.status = Div(text="", width=1200, height=22, name="status")
        self.error = Div(text="", width=1200, height=22, name="error",
                         styles={"color": "#b00020", "font-weight": "bold"})
        self.joint = RadioButtonGroup(labels=[f"joint {j}" for j in range(7)], active=0, name="joint")
        self.joint.on_change("active", lambda a, o, n: self._draw_residual())
        self.cursor = Slider(title="cursor time (s)", start=0.0, end=1.0, value=0.0, step=0.01, width=560,
                             name="cursor")
        self.cursor.on_change("value_throttled", lambda a, o, n: self._move_cursor(n))

        build_figures(self)

        self.toggle_box = column(name="toggles")
        self._build_toggles()
        self.preset_btn = Button(label="diagnose's selection", width=170, name="preset")
        self.preset_btn.on_click(self._apply_preset)
        self.none_btn = Button(label="none", width=80, name="none")
        self.none_btn.on_click(lambda: self._set_enabled({}, touched=True))

        self.cand_src = ColumnDataSource(dict(rank=[], effect=[], joints=[], score=[], sig=[], plaus=[],
                                              after=[], params=[]))
        cols = [TableColumn(field="rank", title="#", width=30), TableColumn(field="effect", title="effect", width=170),
                TableColumn(field="joints", title="joints", width=120),
                TableColumn(field="score", title="evidence", width=80),
                TableColumn(field="sig", title="significant", width=70),
                TableColumn(field="plaus", title="plausible", width=70),
                TableColumn(field="after", title="held-out RMSE alone (Nm)", width=300),
                TableColumn(field="params", title="fitted values", width=500)]
        self.cand_table = DataTable(source=self.cand_src, columns=cols, width=1250, height=260, index_position=None,
                                    name="candidates")
        self.diag_div = Div(text="<i>the diagnosis runs after the log is opened</i>", width=1250, name="diagnosis")

        self.model_out = TextInput(title="calibrated model file to write (new name)", width=420, name="model_out")
        self.save_model_btn = Button(label="save model", button_type="success", width=110, name="save_model",
                                     align="end")
        self.save_model_btn.on_click(self._save_model)
        self.report_out = TextInput(title="report folder to write (new name)", width=420, name="report_out")
        self.save_report_btn = Button(label="save report", width=110, name="save_report", align="end")
        self.save_report_btn.on_click(self._save_report)
        self.val_log = TextInput(title="second log (validation)", width=420, name="val_log")
        self.val_model = TextInput(title="model file", width=420, name="val_model")
        self.val_btn = Button(label="validate", width=110, name="validate", align="end")
        self.val_btn.on_click(self._validate)
        self.ovl_log = TextInput(title="log to overlay", width=420, name="ovl_log")
        self.ovl_offset = Spinner(title="its time offset (s)", value=0.0, step=0.1, width=120, name="ovl_offset")
        self.ovl_btn = Button(label="overlay", width=110, name="overlay", align="end")
        self.ovl_btn.on_click(self._overlay)
        self.ovl_box = column(name="overlays")
        self.saved_div = Div(text="", width=1200, name="saved")

        h = lambda s: Div(text=f"<h3 style='margin:10px 0 2px 0'>{s}</h3>")  # noqa: E731
        self.root = column(
            self.title, row(self.path, self.open_btn, self.files), self.status, self.error,
            h("Where the model fails"), row(self.joint, self.cursor),
            row(column(self.f_time, row(self.f_dq, self.f_q)), self.arm_div),
            h("Effects: toggle on and off (refitted on the fit part; error on the held-out part)"),
            row(self.preset_btn, self.none_btn), self.toggle_box, row(self.f_rmse, self.f_fitp), self.rmse_div,
            self.params_div,
            h("Diagnosis: ranked candidates (each effect alone) and the selected set"), self.diag_div,
            self.cand_table,
            h("Save, validate, overlay"), row(self.model_out, self.save_model_btn),
            row(self.report_out, self.save_report_btn), row(self.val_log, self.val_model, self.val_btn),
            row(self.ovl_log, self.ovl_offset, self.ovl_btn), self.ovl_box, self.saved_div)

    # ------------------------------------------------------------------ polling the shared state
    def poll(self) -> None:
        if self.app.version == self.seen_version:
            return
        self.doc.hold("combine")  # every change of this poll reaches the browser as one message
        try:
            self._poll()
        finally:
            self.doc.unhold()

    def _poll(self) -> None:
        app = self.app
        self.seen_version = app.version
        busy = " <span style='color:#888'>(working...)</span>" if app.busy else ""
        self.status.text = html.escape(app.status) + busy
        self.error.text = html.escape(app.error)
        for b in (self.open_btn, self.save_model_btn, self.save_report_btn, self.val_btn, self.ovl_btn):
            b.disabled = app.busy
        if app.opened is not None and app.log_version != self.seen_log:
            self.seen_log = app.log_version
            self._new_log()
        if app.diagnosis is not None and app.diagnosis is not getattr(self, "_seen_diag", None):
            self._seen_diag = app.diagnosis
            self._new_diagnosis()
        self._draw_overlays()
        self._draw_saved()

    # ------------------------------------------------------------------ a log opened
    def _new_log(self) -> None:
        op = self.app.opened
        self.path.value = op.path
        self.touched = self.preset_applied = False
        self.preset_fit = None
        self.title.text = (f"<h2 style='margin:4px 0'>franka-vs workbench: {html.escape(Path(op.path).name)}</h2>"
                           f"{op.ctx.n} samples at {op.ctx.data.settings.rate:g} Hz, {op.time[-1]:.1f} s; model: "
                           f"{html.escape(self.app.options.model or 'the FER with the log declared tool')}; fit on "
                           f"the first {op.split_time:.1f} s, held out after (orange); opened in "
                           f"<span class='opened-s'>{op.seconds:.2f}</span> s")
        stem = Path(op.path).with_suffix("")
        self.model_out.value = free_name(f"{stem}-calibrated.json")
        self.report_out.value = free_name(f"{stem}-report")
        self.heldout_box.left = op.split_time
        t = op.time
        self.cursor.end = float(t[-1])
        self.cursor.step = max(float(t[-1]) / 2000.0, 0.001)
        # the cursor starts where the error is largest (in noise floors, over the joints)
        k = int(np.argmax(np.max(np.abs(op.y) / op.noise, axis=1)))
        self.cursor.value = float(t[k])
        self.span.location = float(t[k])
        self.joint.active = int(np.argmax(np.abs(op.y[k]) / op.noise))
        self._set_enabled({}, refit=False)
        self._enable_toggles()
        self.baseline = S.refit(op, {})
        self.arm_div.text = "<i>drawing the arm...</i>"
        self._refit(arm=False)
        self.doc.add_timeout_callback(self._draw_arm, 50)  # after the page is usable
        self._drawn = True
        if self._shown:
            self.doc.add_timeout_callback(self.app.page_ready.set, 300)  # then the diagnosis may take the CPU

    def _build_toggles(self) -> None:
        """One row per effect of the library, made with the page (before any log is open, so that the browser lays
        them out while the server reads the log); a log that cannot support an effect disables its row."""
        from franka_vs_gym.validation.effects import REGISTRY

        rows = []
        self.toggles = {}
        for name in REGISTRY.names():
            e = REGISTRY.get(name)
            labels = [f"{j}" for j in range(7)] if e.per_joint else ["on"]
            g = CheckboxButtonGroup(labels=labels, active=[], name=f"toggle_{name}", width=250 if e.per_joint else 60,
                                    disabled=True)
            g.on_change("active", lambda a, o, n: self._toggled())
            self.toggles[name] = g
            tip = html.escape(e.signature or e.description or "")[:140]
            rows.append(row(Div(text=f"<b>{name}</b>", width=190, styles={"padding-top": "6px"}), g,
                            Div(text=f"<span style='color:#666;font-size:85%'>{tip}</span>", width=700)))
        self.skipped_div = Div(text="", width=1200)
        rows.append(self.skipped_div)
        self.toggle_box.children = rows

    def _enable_toggles(self) -> None:
        op = self.app.opened
        for name, g in self.toggles.items():
            g.disabled = name not in op.terms
        self.skipped_div.text = ("not offered on this log: " + "; ".join(
            f"{html.escape(k)} ({html.escape(v[:120])})" for k, v in op.skipped.items())) if op.skipped else ""

    def _enabled(self) -> dict[str, list[int] | None]:
        out: dict[str, list[int] | None] = {}
        for name, g in self.toggles.items():
            if not g.active:
                continue
            out[name] = sorted(g.active) if len(g.labels) == 7 else None
        return out

    def _set_enabled(self, enabled: dict[str, list[int] | None], touched: bool = False, refit: bool = True) -> None:
        self._quiet = True
        try:
            for name, g in self.toggles.items():
                if name not in enabled:
                    g.active = []
                elif len(g.labels) == 7:
                    g.active = sorted(enabled[name] or range(7))
                else:
                    g.active = [0]
        finally:
            self._quiet = False
        self.touched = self.touched or touched
        if refit:
            self._refit()

    def _toggled(self) -> None:
        if getattr(self, "_quiet", False):
            return
        self.touched = True
        self._refit()

    def _apply_preset(self) -> None:
        d = self.app.diagnosis
        if d is None:
            self.error.text = "error: the diagnosis has not finished yet (its progress is shown above)"
            return
        self._set_enabled(S.preset(d), touched=True)

    # ------------------------------------------------------------------ the refit and its figures
    def _refit(self, arm: bool = True) -> None:
        if self.app.opened is None:
            return
        self.doc.hold("combine")  # the new residual, errors and values as one message
        try:
            self._refit_now(arm)
        finally:
            self.doc.unhold()

    def _refit_now(self, arm: bool) -> None:
        op = self.app.opened
        t0 = time.perf_counter()
        try:
            self.current = S.refit(op, self._enabled())
        except Exception as e:
            self.error.text = html.escape(f"error: {one_line(e)}" if is_user_error(e) else
                                          f"internal error: {type(e).__name__}: {one_line(e)}")
            return
        self._draw_residual()
        self._draw_rmse()
        self._draw_fit_percent()
        if arm:  # on the next tick: the figures' changes go to the browser first
            self.doc.add_next_tick_callback(self._draw_arm)
        self.last_toggle_s = time.perf_counter() - t0

    def _draw_residual(self) -> None:
        op, cur = self.app.opened, self.current
        if op is None or cur is None:
            return
        j = int(self.joint.active or 0)
        s = _stride(op.ctx.n)
        d = op.ctx.data
        if getattr(self, "_shown_joint", None) == (op, j) and len(self.src.data["cur"]) == len(op.time[::s]):
            self.src.data["cur"] = cur.residual[::s, j]  # a toggle: only the new residual goes to the browser
        else:
            self.src.data = dict(t=op.time[::s], base=op.y[::s, j], cur=cur.residual[::s, j], dq=d.dq[::s, j],
                                 q=d.q[::s, j])
            self._shown_joint = (op, j)
        nf = float(op.noise[j])
        for b in self.bands:
            b.bottom, b.top = -nf, nf
        self.f_time.title.text = (f"joint {j}: residual tau_J - model (Nm) over time; green band: noise floor "
                                  f"+-{nf:.3f} Nm; orange: held out")
        self.f_dq.title.text = f"joint {j}: residual against velocity"
        self.f_q.title.text = f"joint {j}: residual against position"
        self._draw_overlays()

    def _draw_rmse(self) -> None:
        op, cur, base = self.app.opened, self.current, self.baseline
        xs, vs, cs, ks = [], [], [], []
        for j in range(7):
            xs += [(f"joint {j}", "baseline"), (f"joint {j}", "enabled")]
            vs += [float(base.rmse_heldout[j]), float(cur.rmse_heldout[j])]
            cs += ["#aaaaaa", "#1f77b4"]
            ks += ["baseline model", "with the enabled effects"]
        self.rmse_src.data = dict(x=xs, v=vs, colour=cs, kind=ks)
        self.noise_src.data = dict(x=[(f"joint {j}", k) for j in range(7) for k in ("baseline", "enabled")],
                                   v=[float(op.noise[j]) for j in range(7) for _ in range(2)])
        self.rmse_div.text = rmse_html(op, base, cur)
        self.params_div.text = params_html(cur)
        self._intervals_later(op, cur)

    def _intervals_later(self, op, cur: S.Refit) -> None:
        """The enabled set's intervals on the app's interval thread; shown if the set is still the one enabled."""
        self._ci_token = token = getattr(self, "_ci_token", 0) + 1
        if not cur.params:
            return

        def job() -> None:
            if token != self._ci_token:
                return  # another toggle came since
            try:
                ci = S.intervals(op, cur.enabled)
            except Exception as e:  # shown beside the values; the fit itself stands
                ci = {"_error": one_line(e)}
            if token == self._ci_token:
                self.doc.add_next_tick_callback(lambda: self._show_intervals(token, cur, ci))

        self.app.interval_pool.submit(job)

    def _show_intervals(self, token: int, cur: S.Refit, ci: dict) -> None:
        if token == self._ci_token and cur is self.current:
            self.params_div.text = params_html(cur, ci)

    def _variants(self) -> list[tuple[str, np.ndarray]]:
        out = [("baseline", self.baseline.fit_percent)]
        if self.preset_fit is not None:
            out.append(("diagnose's selection", self.preset_fit.fit_percent))
        out.append(("enabled", self.current.fit_percent))
        for v in self.app.validations[-2:]:
            out.append((f"{Path(v.model).name} on {Path(v.log).name}", v.fit_percent))
        return out

    def _draw_fit_percent(self) -> None:
        variants = self._variants()
        palette = ("#aaaaaa", "#ff7f0e", "#1f77b4", "#2ca02c", "#9467bd")
        xs, vs, cs, ns = [], [], [], []
        for j in range(7):
            for i, (name, fp) in enumerate(variants):
                xs.append((f"joint {j}", name))
                vs.append(float(max(fp[j], -50.0)))  # a variant far worse than the mean is drawn at -50
                cs.append(palette[i % len(palette)])
                ns.append(name)
        if list(self.f_fitp.x_range.factors) != xs:
            self.f_fitp.x_range.factors = xs
        self.fitp_src.data = dict(x=xs, v=vs, colour=cs, variant=ns)

    def _draw_arm(self) -> None:
        op, cur = self.app.opened, self.current
        if op is None or cur is None:
            return
        t = op.time
        k = int(np.clip(np.searchsorted(t, self.cursor.value), 0, len(t) - 1))
        levels = np.abs(cur.residual[k]) / op.noise
        try:
            url = self.arm.png_data_url(op.ctx.data.q[k], levels)
        except NoGL as e:
            self.arm_div.text = f"<div style='color:#b00020;width:420px'>no arm view: {html.escape(str(e))}</div>"
            return
        legend = " ".join(f"<span title='joint {j}'>j{j} {lv:.1f}</span>" for j, lv in enumerate(levels))
        self.arm_div.text = (f"<img src='{url}' width='420' height='360' alt='the arm at t = {t[k]:.2f} s'/>"
                             f"<div style='font-size:85%'>t = {t[k]:.3f} s; |residual| in noise floors (green <= 1, "
                             f"red >= {RED_AT:g}): {legend}</div>")

    def _move_cursor(self, x, set_slider: bool = False) -> None:
        if x is None or self.app.opened is None:
            return
        x = float(np.clip(x, self.cursor.start, self.cursor.end))
        self.span.location = x
        if set_slider:
            self.cursor.value = x
        self._draw_arm()

    # ------------------------------------------------------------------ the diagnosis
    def _new_diagnosis(self) -> None:
        d, op = self.app.diagnosis, self.app.opened
        rows = {k: [] for k in self.cand_src.data}
        for i, c in enumerate(d.ranking):
            rows["rank"].append(i + 1)
            rows["effect"].append(c.effect)
            rows["joints"].append(", ".join(map(str, c.joints)))
            rows["score"].append(round(float(c.score), 1))
            rows["sig"].append("yes" if c.significant else "no")
            rows["plaus"].append("yes" if c.plausible else "no: " + "; ".join(c.problems)[:80])
            rows["after"].append(" ".join(f"{x:.3f}" for x in c.rmse_tau_after))
            rows["params"].append(short(c.params))
        self.cand_src.data = rows
        self.diag_div.text = candidates_html(d)
        try:
            self.preset_fit = S.refit(op, S.preset(d))
        except Exception:  # an effect of the selection not offered as a toggle on this log
            self.preset_fit = None
        if not self.touched and not self.preset_applied:
            self.preset_applied = True
            self._set_enabled(S.preset(d))
        else:
            self._draw_fit_percent()

    # ------------------------------------------------------------------ save, validate, overlay
    def _save_model(self) -> None:
        app, op, enabled, out = self.app, self.app.opened, self._enabled(), self.model_out.value
        if op is None:
            self.error.text = "error: open a log first"
            return

        def work():
            res = S.calibrate(op, enabled, app.progress)
            return S.save_model(op, res, out), res

        def done(r) -> None:
            p, res = r
            app.saved_models.append(str(p))
            app.last_fit = res
            app._set(status=f"saved the calibrated model {p} (effects: {', '.join(res.effects)}); check it with "
                            f"franka-vs compare LOG --model {p}")

        app.submit("saving the calibrated model", work, done)

    def _save_report(self) -> None:
        app, op, enabled, out = self.app, self.app.opened, self._enabled(), self.report_out.value
        if op is None:
            self.error.text = "error: open a log first"
            return
        model_file = app.saved_models[-1] if app.saved_models else None

        def work():
            res = S.calibrate(op, enabled, app.progress)
            return S.save_report(op, res, out, app.diagnosis, model_file, app.progress)

        def done(p) -> None:
            app.saved_reports.append(str(p))
            app._set(status=f"saved the report {p / 'report.html'}")

        app.submit("writing the report", work, done)

    def _validate(self) -> None:
        app, o = self.app, self.app.options
        log, model = self.val_log.value, self.val_model.value or (app.saved_models[-1] if app.saved_models else "")

        def done(v: S.Validation) -> None:
            app.validations.append(v)
            app.overlays.append(S.Overlay(f"{Path(v.log).name} with {Path(v.model).name}", v.time, v.residual))
            app._set(status=f"validated {v.model} on {v.log}: RMSE (Nm) {np.round(v.rmse, 3).tolist()}")

        app.submit("validating on the second log",
                   lambda: S.validate(log, model, tool=o.tool, robot=o.robot, settings=o.settings,
                                      progress=app.progress), done)

    def _overlay(self) -> None:
        app, op, log, off = self.app, self.app.opened, self.ovl_log.value, float(self.ovl_offset.value or 0.0)
        if op is None:
            self.error.text = "error: open a log first"
            return

        def done(ov: S.Overlay) -> None:
            ov.offset = off
            app.overlays.append(ov)
            app._set(status=f"overlaid {ov.log} (offset {off:g} s)")

        app.submit("reading the log to overlay",
                   lambda: S.overlay(log, op.cfg, settings=app.options.settings, progress=app.progress), done)

    def _draw_overlays(self) -> None:
        ovs = self.app.overlays
        j = int(self.joint.active or 0)
        key = (j, tuple((id(ov), ov.offset) for ov in ovs))
        if key == getattr(self, "_overlays_drawn", None):
            return  # unchanged: nothing is sent (a poll must not make the browser redraw the time plot)
        self._overlays_drawn = key
        xs, ys, cs, ls = [], [], [], []
        for i, ov in enumerate(ovs):
            s = _stride(len(ov.time))
            xs.append((ov.time[::s] + ov.offset).tolist())
            ys.append(ov.residual[::s, j].tolist())
            cs.append(OVERLAY_COLOURS[i % len(OVERLAY_COLOURS)])
            ls.append(f"{Path(ov.log).name} (+{ov.offset:g} s)")
        if [c.name for c in self.ovl_box.children] != [f"offset_{i}" for i in range(len(ovs))]:
            spinners = []
            for i, ov in enumerate(ovs):
                sp = Spinner(title=f"time offset of {Path(ov.log).name} (s)", value=ov.offset, step=0.1, width=260,
                             name=f"offset_{i}")
                sp.on_change("value", lambda a, o, n, i=i: self._shift(i, n))
                spinners.append(sp)
            self.ovl_box.children = spinners
        self.ovl_src.data = dict(xs=xs, ys=ys, colour=cs, label=ls)

    def _shift(self, i: int, value) -> None:
        self.app.overlays[i].offset = float(value or 0.0)
        self._draw_overlays()

    def _draw_saved(self) -> None:
        app = self.app
        lines = [f"model: {html.escape(p)}" for p in app.saved_models]
        lines += [f"report: {html.escape(p)}/report.html" for p in app.saved_reports]
        for v in app.validations:
            lines.append(f"{html.escape(Path(v.model).name)} on {html.escape(v.log)}: RMSE (Nm) "
                         f"{' '.join(f'{x:.3f}' for x in v.rmse)}; fit % {' '.join(f'{x:.1f}' for x in v.fit_percent)}"
                         f"; noise floor {' '.join(f'{x:.3f}' for x in v.noise)}")
        fit = getattr(app, "last_fit", None)
        self.saved_div.text = "<br>".join(lines) + (fit_html(fit) if fit is not None else "")
        if app.saved_models and not self.val_model.value:
            self.val_model.value = app.saved_models[-1]
        for box in (self.model_out, self.report_out):  # the next save proposes a new name
            if box.value and box.value in app.saved_models + app.saved_reports:
                box.value = free_name(box.value)
        if self.current is not None and len(app.validations) != getattr(self, "_validations_drawn", 0):
            self._validations_drawn = len(app.validations)
            self._draw_fit_percent()

    # ------------------------------------------------------------------ the log chooser
    def _folder_files(self, path: str) -> list[str]:
        p = Path(os.path.expanduser(path or "."))
        folder = p if p.is_dir() else p.parent
        try:
            return [""] + S.log_files(str(folder))[:500]
        except Exception:
            return [""]

    def _pick(self, value: str) -> None:
        if not value:
            return
        self.path.value = value.rstrip("/") if not value.endswith("/") else value
        if value.endswith("/"):
            self.files.options = self._folder_files(value)
            self.files.value = ""

    def _open(self, path: str) -> None:
        self.files.options = self._folder_files(path)
        self.app.open(path)


def make_document(app: App):
    """The function the Bokeh server calls for each new page."""

    def build(doc) -> None:
        Page(app, doc)

    return build


__all__ = ["Page", "make_document"]
