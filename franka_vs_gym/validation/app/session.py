"""What ``franka-vs workbench`` shows, computed without Bokeh (the page in :mod:`.page` only draws it).

A log is opened once (:func:`open_log`): read and cleaned as ``diagnose`` and ``fit`` read it, the baseline model's
inverse-dynamics residual ``y`` computed, and every library effect's regressor columns built once by the effect's own
code (each effect's shape chosen on ``y`` as ``fit`` chooses it, then cached by the selection engine, with its Gram
matrices on the fit part). A toggle is then :func:`refit`: one joint least-squares solve of the enabled set on the
fit part of ``fit``'s own time split (the first ``1 - HOLDOUT`` of the log, :func:`~..fitting.holdout_split`), by the
selection engine (:class:`~..selection.Engine`), and the residual it leaves everywhere: its RMSE per joint on the
held-out part is what the page reports. The app writes no estimator of its own.

Saving (:func:`calibrate`) runs ``fit``'s own last step on the enabled set (the joint fit on all samples with the
effects' non-linear refinements, the constraints that keep the model physical, the effects written into the model)
and writes the same calibrated-model file ``franka-vs fit -o`` writes; the report is ``fit --report``'s.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from franka_vs_gym.errors import UserError
from franka_vs_gym.validation.effects import REGISTRY, Context, Effect
from franka_vs_gym.validation.effects.base import COULOMB_VC, MAX_DELAY, MIN_DELAY, STRIBECK_VS
from franka_vs_gym.validation.results import Diagnosis, FitResult, rmse
from franka_vs_gym.validation.selection import Engine, Term

Progress = Callable[[str], None]

#: shape parameters with a range (the effects' own search ranges: a value at an end is a fit that hit its bound)
BOUNDS: dict[str, tuple[float, float, str]] = {
    "phi2_s_per_rad": (0.5, 400.0, "s/rad"),  # the sigmoid's width (SigmoidFriction's refinement range)
    "phi3_rad_per_s": (-0.3, 0.3, "rad/s"),  # the sigmoid's offset
    "coulomb_vel_rad_per_s": (min(COULOMB_VC), max(COULOMB_VC), "rad/s"),  # Coulomb smoothing velocities tried
    "v_s_rad_per_s": (min(STRIBECK_VS), max(STRIBECK_VS), "rad/s"),  # Stribeck velocities tried
    "delay_s": (MIN_DELAY, MAX_DELAY, "s"),
}
BOUND_TOL = 1e-3  # relative to the range: closer than this to an end is "at its bound"


def _say(progress: Progress | None, msg: str) -> None:
    if progress is not None:
        progress(msg)


def fit_percent(y: np.ndarray, residual: np.ndarray) -> np.ndarray:
    """Normalised RMSE fit per joint, % (MATLAB ``compare``'s): ``100 (1 - ||y - yhat|| / ||y - mean(y)||)`` with
    ``y - yhat`` the residual; 100 is a perfect model, 0 no better than the mean, negative worse."""
    y = np.asarray(y, dtype=np.float64)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    num = np.linalg.norm(np.asarray(residual, dtype=np.float64), axis=0)
    return 100.0 * (1.0 - num / np.maximum(den, 1e-12))


@dataclass
class Opened:
    """One log opened for the page: the processed log ``data`` (all samples), the model ``cfg`` it is compared
    with, the effects' context ``ctx`` (the log the effects work on, decimated when long), the baseline residual
    ``y`` (N, 7) Nm on ``ctx.data``, the time split (``train``, ``test`` indices), the noise floor (7,) Nm, one term
    per effect the log supports (all joints; ``skipped`` says why the others are not offered) and the engine whose
    only block is the fit part."""

    path: str
    data: Any
    cfg: Any
    ctx: Context
    y: np.ndarray
    train: np.ndarray
    test: np.ndarray
    noise: np.ndarray
    terms: dict[str, Term]
    skipped: dict[str, str]
    engine: Engine
    seconds: float = 0.0
    inputs: list[Path] = field(default_factory=list)

    @property
    def time(self) -> np.ndarray:
        """Seconds from the start of the log, on the effects' samples."""
        return self.ctx.data.time - self.ctx.data.time[0]

    @property
    def split_time(self) -> float:
        return float(self.time[self.test[0]]) if len(self.test) else float(self.time[-1])


def open_log(path: str, *, model: Any = None, tool: str | None = None, robot: Any = None, settings=None,
             topic: str | None = None, rigid_body: bool = False, progress: Progress | None = None) -> Opened:
    """Read, clean and prepare ``path`` (see :class:`Opened`); the log's own errors (a missing file, a format
    that cannot be read, a model file that does not fit) are raised as the CLI raises them."""
    from franka_vs_gym.validation.compare import as_processed, baseline_config
    from franka_vs_gym.validation.fitting import holdout_split
    from franka_vs_gym.validation.loading import load_log
    from franka_vs_gym.validation.logs import sidecar_path
    from franka_vs_gym.validation.signals import decimated

    t0 = time.perf_counter()
    if not str(path).strip():
        raise UserError("no log given: type the path of a log file or folder")
    p = Path(os.path.expanduser(str(path).strip()))
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    _say(progress, f"reading {p.name}")
    log = load_log(str(p), topic=topic)
    _say(progress, "cleaning the log")
    data = as_processed(log, settings)
    cfg = baseline_config(data.log, model, rigid_body, tool=tool, robot=robot, data=data)
    fx = decimated(data)
    _say(progress, f"evaluating the model and its regressors on {fx.n} samples")
    ctx = Context(fx, cfg)
    y = ctx.residual
    train, test = holdout_split(ctx.n)
    eng = Engine(ctx, y, [train])
    terms: dict[str, Term] = {}
    skipped: dict[str, str] = {}
    _say(progress, "building each effect's regressor columns")
    for name in REGISTRY.names():
        e = REGISTRY.get(name)
        try:
            term = Term(e, e.shape(ctx, y), list(range(7)) if e.per_joint else None)
            eng.design(term)
        except Exception as exc:  # an effect this log cannot support (e.g. link inertials on a slow log)
            skipped[name] = " ".join(str(exc).split()) or type(exc).__name__
            continue
        terms[name] = term
    inputs = [p, sidecar_path(p), p.with_suffix(".json")] + ([Path(model)] if isinstance(model, (str, Path)) else [])
    return Opened(str(p), data, cfg, ctx, y, train, test, data.noise.copy(), terms, skipped, eng,
                  time.perf_counter() - t0, inputs)


@dataclass
class Refit:
    """The enabled set (effect -> its joints, ``None`` for an effect shared by all joints) fitted on the fit part:
    the residual it leaves (N, 7) Nm everywhere, its RMSE per joint on the fit and held-out parts, fit % on the
    held-out part, each effect's fitted values (as ``diagnose`` reports them) and the parameters at a bound."""

    enabled: dict[str, list[int] | None]
    residual: np.ndarray
    rmse_fit: np.ndarray
    rmse_heldout: np.ndarray
    fit_percent: np.ndarray
    params: dict[str, dict[str, Any]]
    at_bound: list[str]
    seconds: float


def _terms(op: Opened, enabled: dict[str, list[int] | None]) -> list[Term]:
    out = []
    for name, joints in enabled.items():
        base = op.terms.get(name)
        if base is None:
            raise UserError(f"effect {name!r} is not available on this log"
                            + (f": {op.skipped[name]}" if name in op.skipped else ""))
        if base.effect.per_joint:
            js = sorted({int(j) for j in (joints or [])})
            if not js:
                continue
            out.append(Term(base.effect, base.shape, js))
        else:
            out.append(Term(base.effect, base.shape, None))
    return out


def refit(op: Opened, enabled: dict[str, list[int] | None]) -> Refit:
    """Fit the enabled set on the fit part (one solve from the cached Gram matrices) and measure what it leaves."""
    t0 = time.perf_counter()
    terms = _terms(op, enabled)
    if terms:
        sf = op.engine.fit(terms, cv=False)
        residual = op.engine.residual(sf)
        params = {t.effect.name: {**t.effect.public(f), "joints": list(map(int, f.joints))}
                  for t, f in zip(terms, sf.fits, strict=True)}
    else:
        residual, params = op.y, {}
    tau = op.ctx.data.tau
    warn = [w for name, p in params.items() for w in bound_warnings(name, p)]
    return Refit({t.effect.name: (list(t.joints) if t.joints is not None else None) for t in terms}, residual,
                 rmse(residual[op.train]), rmse(residual[op.test]), fit_percent(tau[op.test], residual[op.test]),
                 params, warn, time.perf_counter() - t0)


def intervals(op: Opened, enabled: dict[str, list[int] | None]) -> dict[str, dict[str, Any]]:
    """95 % intervals of the enabled set's values as :func:`refit` fits them (the intervals ``diagnose`` and
    ``fit`` attach, :func:`~franka_vs_gym.validation.uncertainty.confidence`), by effect; slower than the refit,
    so the page asks for them after it has drawn a toggle."""
    from franka_vs_gym.validation.uncertainty import confidence

    terms = _terms(op, enabled)
    if not terms:
        return {}
    sf = op.engine.fit(terms, cv=False)
    conf = confidence(op.ctx, [t.effect for t in terms], sf.fits, op.y)
    return {t.effect.name: {**ci, "joints": list(map(int, f.joints))}
            for t, f, ci in zip(terms, sf.fits, conf.params_ci95, strict=True)}


def bound_warnings(effect: str, params: dict[str, Any], ci95: dict[str, Any] | None = None) -> list[str]:
    """One line per fitted shape parameter of ``effect`` that sits at an end of its range (:data:`BOUNDS`), with
    its 95 % interval when ``ci95`` has it: the fit would have gone further, so the value is a limit, not an
    estimate."""
    out = []
    joints = params.get("joints")
    for key, (lo, hi, unit) in BOUNDS.items():
        if key not in params or params[key] is None:
            continue
        v = np.atleast_1d(np.asarray(params[key], dtype=object))
        tol = BOUND_TOL * (hi - lo)
        for i, x in enumerate(v):
            if x is None or (len(v) == 7 and joints is not None and i not in joints):
                continue
            x = float(x)
            end = lo if abs(x - lo) <= tol else hi if abs(x - hi) <= tol else None
            if end is None:
                continue
            where = f" joint {i}" if len(v) == 7 else ""
            ci = ""
            if ci95 and ci95.get(key) is not None:
                c = ci95[key][i] if len(v) == 7 else ci95[key]
                if c is not None:
                    ci = f", 95% interval [{c[0]:.4g}, {c[1]:.4g}]"
            out.append(f"{effect} {key}{where} = {x:.4g} {unit} sits at its bound {end:g}{ci}")
    return out


def preset(d: Diagnosis) -> dict[str, list[int] | None]:
    """The diagnosis' selected set as toggles (the effects of the measured-torque channel; a delay found on the
    command channel is another residual and is not offered as a toggle)."""
    out: dict[str, list[int] | None] = {}
    for s in d.selection:
        if s.channel != "inverse_dynamics" or s.effect not in REGISTRY.names():
            continue
        out[s.effect] = list(map(int, s.joints)) if REGISTRY.get(s.effect).per_joint else None
    return out


class _StageSink:
    """Stands in for the terminal's progress line while a long job runs: each stage line goes to ``progress``."""

    def __init__(self, progress: Progress) -> None:
        self.progress = progress

    def write(self, text: str, file: Any = None) -> None:
        self.progress(text.removeprefix("[franka-vs] "))

    def set_description_str(self, text: str) -> None:
        self.write(text)

    def close(self) -> None:
        pass


@contextlib.contextmanager
def stages_to(progress: Progress | None):
    """Within: the workbench's progress stages (``compare.progress``) go to ``progress`` instead of stderr."""
    from franka_vs_gym.validation.compare import _Progress

    if progress is None:
        yield
        return
    old = (_Progress.verbose, _Progress.bar)
    _Progress.verbose, _Progress.bar = True, _StageSink(progress)
    try:
        yield
    finally:
        _Progress.verbose, _Progress.bar = old


def run_diagnosis(op: Opened, progress: Progress | None = None) -> Diagnosis:
    """``diagnose`` on the opened log and model, its stages reported to ``progress``."""
    from franka_vs_gym.validation.diagnose import diagnose

    with stages_to(progress):
        return diagnose(op.data, op.cfg, verbose=True)


def slim(d: Diagnosis) -> Diagnosis:
    """The diagnosis without what the page does not read (its context, processed log, residual and each effect's
    torque: hundreds of MB on a long log), to send it from the process that computed it."""
    from dataclasses import replace

    ranking = [replace(c, fits=[], terms=[]) for c in d.ranking]
    return replace(d, ranking=ranking, context=None, data=None, residual=None, contributions={})


def diagnose_file(path: str, options: dict[str, Any], send: Callable[[tuple[str, Any]], None]) -> None:
    """In a process of its own (the server stays responsive): read ``path`` as :func:`open_log` does, diagnose it,
    and ``send`` each stage as ``("progress", line)``, then ``("done", slim diagnosis)`` or ``("error", exc)``."""
    from franka_vs_gym.validation.compare import as_processed, baseline_config
    from franka_vs_gym.validation.diagnose import diagnose
    from franka_vs_gym.validation.loading import load_log

    def say(msg: str) -> None:
        send(("progress", f"diagnosing: {msg}"))

    try:
        say("reading the log")
        data = as_processed(load_log(path, topic=options.get("topic")), options.get("settings"))
        cfg = baseline_config(data.log, options.get("model"), options.get("rigid_body", False),
                              tool=options.get("tool"), robot=options.get("robot"), data=data)
        with stages_to(say):
            d = diagnose(data, cfg, verbose=True)
        send(("done", slim(d)))
    except Exception as e:  # sent to the page (a user's error as one line, a bug with its type)
        send(("error", e))


def calibrate(op: Opened, enabled: dict[str, list[int] | None], progress: Progress | None = None) -> FitResult:
    """``fit``'s last step on the enabled set and joints: the joint fit on all samples with the effects' non-linear
    refinements, each fit constrained as the model can take it and written into the model; the error before and
    after with the calibrated model, the held-out figures of the page, the intervals. The calibrated model is
    ``result.after``."""
    from franka_vs_gym.validation.evaluate import evaluate
    from franka_vs_gym.validation.fitting import apply_fits, fit_jointly
    from franka_vs_gym.validation.structure import assumptions_of
    from franka_vs_gym.validation.uncertainty import confidence

    terms = _terms(op, enabled)
    if not terms:
        raise UserError("no effect is enabled: toggle at least one effect on before saving a calibrated model")
    for t in terms:
        if type(t.effect).apply is Effect.apply:
            raise UserError(f"effect {t.effect.name!r} can be diagnosed but not written into a model: "
                            f"{t.effect.not_applicable}; toggle it off to save")
    ctx, y, cfg, data = op.ctx, op.y, op.cfg, op.data
    spec = [(t.effect, t.joints) for t in terms]
    held = refit(op, enabled)
    with stages_to(progress):
        from franka_vs_gym.validation.compare import progress as say

        def stage(msg: str, _: bool) -> None:
            say(msg, progress is not None)

        stage(f"fitting {[t.effect.name for t in terms]} on all samples", True)
        fits = fit_jointly(ctx, spec, y, np.arange(ctx.n), refine=True)
        members = [t.effect for t in terms]
        implausible = {e.name: [m for _, m in sorted(p.items())] for e, f in zip(members, fits, strict=True)
                       if (p := e.problems(ctx, f))}
        new, applied, notes = apply_fits(cfg, ctx, members, fits)
        kept = [(e, f) for e, f in zip(members, applied, strict=True) if f is not None]
        members, fits = [e for e, _ in kept], [f for _, f in kept]
        names = [e.name for e in members]
        new = new.copy(notes={**new.notes, "calibrated_on": str(data.log.source), "effects": names,
                              "fitted_with": "franka-vs workbench"})
        stage("re-comparing with the calibrated model", True)
        r_after = data.tau - evaluate(new, data).predicted
        y_full = y if ctx.data is data else data.tau - evaluate(cfg, data).predicted
        params = {e.name: {**e.public(f), "joints": list(map(int, f.joints))} for e, f in zip(members, fits,
                                                                                           strict=True)}
        for name, probs in implausible.items():
            if name in params:
                params[name]["problems"] = probs
        n_fit, n_test = len(op.train), len(op.test)
        rate = ctx.data.settings.rate
        holdout = {"split": f"time split: fit on the first {100 * len(op.train) / ctx.n:.0f}% ({n_fit / rate:.1f} s), "
                            f"validate on the last {100 * n_test / ctx.n:.0f}% ({n_test / rate:.1f} s) (the "
                            "workbench's linear refit)",
                   "rmse_tau_before": np.round(rmse(y[op.test]), 4).tolist(),
                   "rmse_tau_after": np.round(held.rmse_heldout, 4).tolist(),
                   "rmse_tau_total_before": round(float(rmse(rmse(y[op.test]))), 4),
                   "rmse_tau_total_after": round(float(rmse(held.rmse_heldout)), 4), "dropped": [], "added": [],
                   "joints_added": {}}
        res = FitResult(cfg, new, names, fits, params, rmse(y_full), rmse(r_after), op.noise.copy(), data, y_full,
                        r_after, holdout, assumptions_of(data, cfg), dict(notes))
        if members:
            stage("95% intervals of the fitted parameters", True)
            try:
                conf = confidence(ctx, members, fits, y)
            except Exception as exc:  # a plug-in whose contribution fails off its fitted values: keep the fit
                res.unidentifiable = [f"intervals not computed: {type(exc).__name__}: {exc}"]
            else:
                for e, ci in zip(members, conf.params_ci95, strict=True):
                    res.params_ci95[e.name] = {**ci, "joints": params[e.name]["joints"]}
                res.correlations = [c for cs in conf.correlations for c in cs]
                res.unidentifiable = list(dict.fromkeys(u for us in conf.unidentifiable for u in us))
        res.contributions = {e.name: e.contribution(ctx, f) for e, f in zip(members, fits, strict=True)}
        res.contribution_time = ctx.data.time
    return res


def _new_name(path: str, what: str, inputs: list[Path], folder: bool) -> Path:
    """``path`` checked as a new output: never an existing file or folder (the page overwrites nothing: a new name
    is needed), never an input."""
    from franka_vs_gym.io import check_output

    if not str(path).strip():
        raise UserError(f"no {what} path given")
    p = Path(os.path.expanduser(str(path).strip()))
    if os.path.lexists(p):
        raise FileExistsError(f"{what} {p} exists; nothing is overwritten here: choose a new name")
    return check_output(p, False, inputs, what, folder=folder)


def save_model(op: Opened, res: FitResult, path: str) -> Path:
    """Write the calibrated model ``res.after`` to the new file ``path`` (the ``franka-vs fit -o`` format)."""
    from franka_vs_gym.io import OutputSet

    p = _new_name(path, "calibrated model file", op.inputs, folder=False)
    with OutputSet(force=False, inputs=op.inputs) as out:
        res.after.save(out.file(p, what="calibrated model file"), overwrite=True)
    return p


def save_report(op: Opened, res: FitResult, folder: str, diagnosis: Diagnosis | None = None,
                model_file: str | None = None, progress: Progress | None = None) -> Path:
    """Write ``fit --report``'s report (report.html, report.md and figures) of the shown set into the new folder
    ``folder``."""
    from franka_vs_gym.io import OutputSet
    from franka_vs_gym.validation.cli_common import write_views
    from franka_vs_gym.validation.compare import compare

    p = _new_name(folder, "report folder", op.inputs, folder=True)
    with stages_to(progress), OutputSet(force=False, inputs=op.inputs) as out:
        tmp = out.folder(p, what="report folder")
        cmp_after = compare(res.data, res.after, do_replay=False)
        write_views(cmp_after, tmp, None, fit=res, model_file=model_file, verbose=True)
    return p


@dataclass
class Validation:
    """A saved model compared with another log: the log, the model file, RMSE (7,) Nm, fit % (7,), the noise floor
    (7,) and the residual (N, 7) on the log's time (s from its start)."""

    log: str
    model: str
    rmse: np.ndarray
    fit_percent: np.ndarray
    noise: np.ndarray
    time: np.ndarray
    residual: np.ndarray


def validate(path: str, model_file: str, *, tool: str | None = None, robot: Any = None, settings=None,
             progress: Progress | None = None) -> Validation:
    """The saved model's error on another log (``franka-vs compare LOG --model FILE`` without the replay)."""
    from franka_vs_gym.validation.compare import compare

    if not str(path).strip():
        raise UserError("no log given to validate on: type the path of a second log")
    if not str(model_file).strip():
        raise UserError("no model to validate: save a calibrated model first or type the path of a model file")
    p = _existing(path)
    with stages_to(progress):
        res = compare(str(p), model_file, tool=tool, robot=robot, settings=settings, do_replay=False,
                      verbose=progress is not None)
    t = res.data.time - res.data.time[0]
    return Validation(str(p), str(model_file), res.rmse_tau, fit_percent(res.data.tau, res.residual),
                      res.noise_floor, t, res.residual)


def _existing(path: str) -> Path:
    """A path typed in the page (``~`` expanded), or the reader's own error where nothing is there."""
    p = Path(os.path.expanduser(str(path).strip()))
    if not p.exists():
        raise FileNotFoundError(2, "No such file or directory", str(p))
    return p


@dataclass
class Overlay:
    """Another log drawn over the first: its baseline residual (N, 7) Nm on its time (s from its start), shifted
    by ``offset`` s."""

    log: str
    time: np.ndarray
    residual: np.ndarray
    offset: float = 0.0


def overlay(path: str, cfg: Any, *, settings=None, progress: Progress | None = None) -> Overlay:
    """Another log's residual with the model the page compares (for the overlay)."""
    from franka_vs_gym.validation.compare import compare

    if not str(path).strip():
        raise UserError("no log given to overlay: type the path of a log")
    p = _existing(path)
    with stages_to(progress):
        res = compare(str(p), cfg, settings=settings, do_replay=False, verbose=progress is not None)
    return Overlay(str(p), res.data.time - res.data.time[0], res.residual)


def log_files(folder: str) -> list[str]:
    """The entries of ``folder`` a log may be (files and folders, hidden ones and sidecars left out), sorted."""
    p = Path(os.path.expanduser(str(folder).strip() or "."))
    if not p.is_dir():
        raise UserError(f"{p} is not a folder")
    out = []
    for c in sorted(p.iterdir()):
        if c.name.startswith(".") or c.name.endswith((".npz.json", ".csv.json")):
            continue
        out.append(str(c) + ("/" if c.is_dir() else ""))
    return out


__all__ = ["BOUNDS", "Opened", "Overlay", "Refit", "Validation", "bound_warnings", "calibrate", "diagnose_file",
           "fit_percent", "intervals", "log_files", "open_log", "overlay", "preset", "refit", "run_diagnosis",
           "save_model", "save_report", "slim", "stages_to", "validate"]
