"""Fit effects and write them into the model: ``fit_effects`` (``franka-vs fit``), the held-out check beside it,
the joint fit of several effects (:func:`fit_jointly`) and their application to a model configuration
(:func:`apply_fits`). ``fit --add auto`` fits the selection :func:`~franka_vs_gym.validation.diagnose.diagnose`
makes."""

from __future__ import annotations

from typing import Any

import numpy as np

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.validation.compare import as_processed, baseline_config, progress, rmse
from franka_vs_gym.validation.diagnose import FOLDS, HOLDOUT, _Selector, command_channel_delay, diagnose
from franka_vs_gym.validation.effects import COMMAND_DELAY, Context, Effect, Fit, NotApplicable, get_effect
from franka_vs_gym.validation.evaluate import evaluate
from franka_vs_gym.validation.logs import MeasurementLog
from franka_vs_gym.validation.results import FitResult
from franka_vs_gym.validation.selection import Engine, Term, contiguous_folds
from franka_vs_gym.validation.signals import CleanSettings, ProcessedLog, decimated


def holdout_split(n: int, frac: float = HOLDOUT) -> tuple[np.ndarray, np.ndarray]:
    """Time split for held-out validation: the first (1 - frac) of the log fits, the last frac validates."""
    k = int(round(n * (1 - frac)))
    return np.arange(k), np.arange(k, n)


def fit_jointly(ctx: Context, spec, y: np.ndarray, idx: np.ndarray, refine: bool) -> list[Fit]:
    """Fit the effects of ``spec`` [(effect, joints)] together on samples idx: the joint linear least-squares
    solution (shapes chosen on the residual) as the start, then alternating passes in which each effect is re-fitted
    to what the others leave (its own fit: e.g. the sigmoid as a replacement of the model's), with the non-linear
    refinements inside when ``refine``."""
    eng = Engine(ctx, y, [np.asarray(idx)])
    terms = [Term(e, e.shape(ctx, y), (list(j) if j is not None else list(range(7))) if e.per_joint else None)
             for e, j in spec]
    contrib = eng.contributions(eng.fit(terms, cv=False))
    fits: list[Fit | None] = [None] * len(spec)
    for _ in range(2 if len(spec) > 1 else 1):
        for i, (e, joints) in enumerate(spec):
            others = sum((contrib[m] for m in range(len(spec)) if m != i), np.zeros_like(y))
            f = e.fit(ctx, y - others, idx)
            if joints is not None:
                f.joints = list(joints)
            if refine:
                f = e.refine(ctx, y - others, f)
                if joints is not None:
                    f.joints = list(joints)
            fits[i] = f
            contrib[i] = e.contribution(ctx, f)
    return fits  # type: ignore[return-value]


def apply_fits(cfg: ModelConfig, ctx: Context, members: list[Effect],
                fits: list[Fit]) -> tuple[ModelConfig, list[Fit | None], dict[str, str]]:
    """Write fitted effects into ``cfg`` as the model can take them: each fit first constrained
    (:meth:`Effect.constrain`: e.g. friction kept dissipative, link inertials physically consistent), then applied;
    a joint whose friction law would still push it is left out, and an effect the model cannot take is not applied.
    Returns the configuration, the fits as applied (None: not applied) and what was constrained or left out, by
    effect (one line each). Effects that constrain themselves are applied last, against the law the others made."""
    from franka_vs_gym.model.checks import NotDissipative

    notes: dict[str, str] = {}
    applied: list[Fit | None] = list(fits)
    order = sorted(range(len(members)), key=lambda i: type(members[i]).constrain is not Effect.constrain)
    new = cfg
    for i in order:
        e, f = members[i], fits[i]
        f, said = e.constrain(ctx, new, f)
        msgs = [said] if said else []
        out = None
        while out is None:
            try:
                out = e.apply(new, f)
            except NotDissipative as err:
                if err.joint in f.joints and len(f.joints) > 1:
                    msgs.append(f"joint {err.joint} left out: {err}")
                    f = Fit(f.effect, f.theta, [j for j in f.joints if j != err.joint])
                    continue
                msgs.append(f"not applied: {err}")
                break
            except (NotApplicable, ValueError) as err:  # e.g. a gravity whose norm is not Earth's
                msgs.append(f"not applied: {' '.join(str(err).split())}")
                break
        applied[i] = f if out is not None else None
        if out is not None:
            new = out
        if msgs:
            notes[e.name] = "; ".join(msgs)
    return new, applied, notes


def fit_effects(log: MeasurementLog | ProcessedLog | str, effects: list[str], model: Any = None, *,
                rigid_body: bool = False, settings: CleanSettings | None = None, verbose: bool = False,
                holdout: float | None = HOLDOUT, tool: str | None = None, robot: Any = None) -> FitResult:
    """Fit ``effects`` (names, or ["auto"] for the diagnosis' selection) and apply them to the model configuration
    (model and plant), then re-compare.

    ``["auto"]`` fits what :func:`diagnose` selects on the same data with the same model, robot and tool (the
    effects, their joints and the delay's channel): one selection, the one ``franka-vs diagnose`` shows. The held-out
    check is reported beside the fit and does not change that set: an effect whose removal does not raise the
    held-out RMSE is named in ``holdout["no_gain"]`` and in the notes, and kept (``dropped``, ``added`` and
    ``joints_added`` stay empty). An effect the fit cannot keep (the
    model cannot take it, e.g. a gravity whose norm is not Earth's once fitted on the whole log) is dropped with its
    reason in the notes, and the others are fitted again without it.

    Named effects: held-out validation (default, ``holdout`` = 0.25): the effects are first fitted on the first 75%
    of the log and the RMSE of the full calibrated model is measured on the last 25%; an effect whose removal does
    not raise that held-out RMSE is dropped (``dropped`` says which). The kept effects are then fitted on the whole
    log (with the non-linear refinements) for the final model. ``holdout=None`` skips the check."""
    from franka_vs_gym.validation.structure import assumptions_of

    data = as_processed(log, settings)
    cfg = baseline_config(data.log, model, rigid_body, tool=tool, robot=robot, data=data)
    joints_of: dict[str, list[int]] = {}
    fit_notes: dict[str, str] = {}  # effect -> what was constrained, left out or not applied, and why
    auto = [e.strip() for e in effects] == ["auto"]
    command_channel = False
    if auto:
        # the diagnosis as `franka-vs diagnose` makes it on the same data: its selection is the set fitted (the
        # robot settled above: --robot, or the log's declaration)
        d = diagnose(data, model, rigid_body=rigid_body, tool=tool, robot=cfg.robot, verbose=verbose)
        cfg = d.config
        names = d.selected
        ctx = d.context
        joints_of = {s.effect: s.joints for s in d.selection if s.channel != "command"}
        command_channel = any(s.effect == "delay" and s.channel == "command" for s in d.selection)
        progress(f"auto: selected {names or 'nothing (verdict none)'}", verbose)
        for n in names:  # named by the diagnosis but not writable into a model: said, not handed to the fit
            e = get_effect(n)
            if type(e).apply is Effect.apply:
                fit_notes[n] = f"diagnosed but not fitted: {e.not_applicable}"
                progress(f"auto: {n} {fit_notes[n]}", verbose)
        names = [n for n in names if n not in fit_notes]
    else:
        names = []
        for e in (part for item in effects for part in item.split("+")):
            n = get_effect(e).name
            if n in names:
                raise ValueError(f"effect {n!r} given twice")
            names.append(n)
        progress(f"evaluating the baseline model and regressors on {data.n} samples", verbose)
        ctx = Context(decimated(data), cfg)
    for n in names:
        e = get_effect(n)
        if type(e).apply is Effect.apply:
            raise ValueError(f"effect {n!r} can be diagnosed but not applied: {e.not_applicable}")
    y = ctx.residual
    noise = data.noise
    fl = contiguous_folds(ctx.n, FOLDS)
    command_fit = None
    if auto and command_channel and ctx.cmd_residual is not None:  # the channel the diagnosis named
        command_fit = COMMAND_DELAY.fit(ctx, ctx.cmd_residual, np.arange(ctx.n))
        names = [n for n in names if n != "delay"]
    elif not auto and "delay" in names and ctx.cmd_residual is not None:
        progress("delay: choosing the channel (measured torque vs motion, or vs command)", verbose)
        eng = Engine(ctx, y, fl)
        sel = _Selector(ctx, eng, noise, [get_effect("delay")], False)
        cur = eng.fit([])
        meas = sel.try_add([], cur, sel._neff(cur), get_effect("delay"))
        if not meas.ok:
            cmd = command_channel_delay(ctx, fl, noise, False)
            if cmd is not None and cmd.ok:
                command_fit = COMMAND_DELAY.fit(ctx, ctx.cmd_residual, np.arange(ctx.n))
                names = [n for n in names if n != "delay"]
    members = [get_effect(n) for n in names]
    spec = []
    for e in members:
        if e.per_joint and e.name not in joints_of:
            progress(f"held-out joint selection for {e.name}", verbose)
            eng = Engine(ctx, y, fl)
            sel = _Selector(ctx, eng, noise, [e], False)
            cur = eng.fit([])
            c = sel.try_add([], cur, sel._neff(cur), e)
            joints_of[e.name] = c.joints if c.joints else [j for j in range(7) if c.joint_scores[j] > 0]
        spec.append((e, joints_of.get(e.name) if e.per_joint else None))
    dropped: list[str] = []
    holdout_info: dict[str, Any] | None = None
    if holdout and (spec or auto):
        train, test = holdout_split(ctx.n, holdout)
        sub = ctx.data.subset(test)

        def heldout_rmse(sp) -> np.ndarray:
            new = cfg
            if sp:
                ok = [(e, f) for (e, _), f in zip(sp, fit_jointly(ctx, sp, y, train, refine=False), strict=True)
                      if not any(e.problems(ctx, f).values())]  # not applied with implausible values
                if ok:
                    new = apply_fits(cfg, ctx, [e for e, _ in ok], [f for _, f in ok])[0]
            return rmse(sub.tau - evaluate(new, sub).predicted)

        progress(f"held-out check: fitting on the first {100 * (1 - holdout):.0f}% of the log, validating on the "
                 f"last {100 * holdout:.0f}%", verbose)
        base_h = rmse(y[test])
        full_h = heldout_rmse(spec)
        no_gain: list[str] = []
        for i, (e, _) in enumerate(spec if auto else []):  # reported beside the fit; the set stays the diagnosis'
            rest = spec[:i] + spec[i + 1:]
            h = heldout_rmse(rest) if rest else base_h
            if float(np.sum(h ** 2)) <= float(np.sum(full_h ** 2)):
                no_gain.append(e.name)
                why = (f"held-out check: the last {100 * holdout:.0f}% of the log has a total RMSE of "
                       f"{float(rmse(h)):.4f} Nm without it, {float(rmse(full_h)):.4f} Nm with it (fitted on the "
                       "first part): it does not lower the held-out error; kept, as the diagnosis selected it")
                fit_notes[e.name] = f"{fit_notes[e.name]}; {why}" if e.name in fit_notes else why
                progress(f"{e.name}: {why}", verbose)
        changed = not auto
        while changed and spec:
            changed = False
            for i, (e, _) in enumerate(spec):
                rest = spec[:i] + spec[i + 1:]
                h = heldout_rmse(rest) if rest else base_h
                if float(np.sum(h ** 2)) <= float(np.sum(full_h ** 2)):
                    progress(f"held-out check: {e.name} does not lower the held-out RMSE; dropped", verbose)
                    dropped.append(e.name)
                    spec, full_h, changed = rest, h, True
                    break
        added: list[str] = []  # the held-out check adds no effect and no joint (named effects and 'auto' alike)
        widened: dict[str, list[int]] = {}
        holdout_info = {"split": f"time split: fit on the first {100 * (1 - holdout):.0f}% "
                                 f"({len(train) / data.settings.rate:.1f} s), validate on the last "
                                 f"{100 * holdout:.0f}% ({len(test) / data.settings.rate:.1f} s)",
                        "rmse_tau_before": np.round(base_h, 4).tolist(),
                        "rmse_tau_after": np.round(full_h, 4).tolist(),
                        "rmse_tau_total_before": round(float(rmse(base_h)), 4),
                        "rmse_tau_total_after": round(float(rmse(full_h)), 4), "dropped": dropped,
                        "added": added, "joints_added": widened, "no_gain": no_gain}
        members = [e for e, _ in spec]
        names = [e.name for e in members]
    progress(f"fitting {names} on all samples", verbose)
    fits = fit_jointly(ctx, spec, y, np.arange(ctx.n), refine=True) if spec else []
    implausible: dict[str, list[str]] = {}
    earlier_notes = dict(fit_notes)  # the diagnosis' and the held-out check's; each attempt's own are kept apart
    attempt_notes: dict[str, str] = {}
    dropped_notes: dict[str, str] = {}  # why each effect the model could not take was dropped
    for _attempt in range(len(members) + 1):
        implausible = {}
        for e, f in zip(members, fits, strict=True):
            probs = e.problems(ctx, f)  # also prepares what apply needs (e.g. consistent link inertials)
            if probs:
                implausible[e.name] = [m for _, m in sorted(probs.items())]
                progress(f"warning: {e.name} fits with implausible values: {'; '.join(implausible[e.name])}",
                         verbose)
        new, applied, notes = apply_fits(cfg, ctx, members, fits)
        attempt_notes = notes
        for n, why in notes.items():
            progress(f"{n}: {why}", verbose)
        if all(f is not None for f in applied):
            break
        # an effect the model cannot take is dropped and the others are fitted again without it. Where several
        # cannot be taken, one may fail only through another that took its share (link inertials fitted with a
        # tilt absorbed part of it and left |g| = 8.8 m/s^2): they are dropped one at a time, each time the one
        # whose removal leaves the largest set the model takes, then the smallest squared residual
        failed = [i for i, f in enumerate(applied) if f is None]
        keep = [i for i, f in enumerate(applied) if f is not None]
        refit = None
        if len(failed) > 1:
            best = None
            for i in failed:
                k_i = [k for k in range(len(spec)) if k != i]
                f_i = fit_jointly(ctx, [spec[k] for k in k_i], y, np.arange(ctx.n), refine=True)
                for m, f in zip([members[k] for k in k_i], f_i, strict=True):
                    m.problems(ctx, f)  # prepares what apply needs, as above
                _, a_i, _ = apply_fits(cfg, ctx, [members[k] for k in k_i], f_i)
                r = y - sum((members[k].contribution(ctx, f) for k, f in zip(k_i, a_i, strict=True)
                             if f is not None), np.zeros_like(y))
                rank = (sum(f is not None for f in a_i), -float(np.sum(r ** 2)))
                if best is None or rank > best[0]:
                    best = (rank, k_i, f_i)
            assert best is not None
            keep, refit = best[1], best[2]
        dropped_notes.update({names[i]: notes.get(names[i], "not applied") for i in range(len(names))
                              if i not in keep})
        spec = [spec[i] for i in keep]
        members, names = [members[i] for i in keep], [names[i] for i in keep]
        fits = refit if refit is not None else (fit_jointly(ctx, spec, y, np.arange(ctx.n), refine=True)
                                                if spec else [])
    else:
        new, applied, notes = apply_fits(cfg, ctx, members, fits)
        attempt_notes = notes
        keep = [i for i, f in enumerate(applied) if f is not None]
        members, names = [members[i] for i in keep], [names[i] for i in keep]
    fits = [f for f in applied if f is not None]
    for n, why in [*dropped_notes.items(), *attempt_notes.items()]:  # the final attempt's, and why each was dropped
        earlier_notes[n] = f"{earlier_notes[n]}; {why}" if n in earlier_notes else why
    fit_notes.clear()
    fit_notes.update(earlier_notes)
    if command_fit is not None:
        new = COMMAND_DELAY.apply(new, command_fit)
        members, fits, names = members + [COMMAND_DELAY], fits + [command_fit], names + ["delay"]
    new = new.copy(notes={**new.notes, "calibrated_on": str(data.log.source), "effects": names})
    progress("re-comparing with the calibrated model", verbose)
    ev = evaluate(new, data)
    r_after = data.tau - ev.predicted
    y_full = y if ctx.data is data else data.tau - evaluate(cfg, data).predicted
    params = {e.name: {**e.public(f), "joints": list(map(int, f.joints))} for e, f in zip(members, fits, strict=True)}
    for name, probs in implausible.items():
        if name in params:
            params[name]["problems"] = probs
    res = FitResult(cfg, new, names, fits, params, rmse(y_full), rmse(r_after), noise.copy(), data, y_full, r_after,
                    holdout_info, assumptions_of(data, cfg, tool), fit_notes)
    if len(members) > (command_fit is not None):
        from franka_vs_gym.validation.uncertainty import confidence

        progress("95% intervals of the fitted parameters", verbose)
        # the jointly fitted effects that the model took (a command-channel delay is fitted on its own channel)
        k = len(members) - (command_fit is not None)
        try:
            conf = confidence(ctx, members[:k], fits[:k], y)
        except Exception as exc:  # e.g. a plug-in whose contribution fails off its fitted values: keep the fit
            res.unidentifiable = [f"intervals not computed: {type(exc).__name__}: {exc}"]
        else:
            for e, ci in zip(members[:k], conf.params_ci95, strict=True):
                res.params_ci95[e.name] = {**ci, "joints": params[e.name]["joints"]}
            res.correlations = [c for cs in conf.correlations for c in cs]
            res.unidentifiable = list(dict.fromkeys(u for us in conf.unidentifiable for u in us))
    if command_fit is not None:  # the delay on the command channel: its own fit, its own residual
        from franka_vs_gym.validation.uncertainty import confidence

        conf = confidence(ctx, [COMMAND_DELAY], [command_fit], ctx.cmd_residual)
        res.params_ci95["delay"] = {**conf.params_ci95[0], "joints": params["delay"]["joints"]}
    res.contributions = {e.name: e.contribution(ctx, f) for e, f in zip(members, fits, strict=True)
                         if f is not command_fit}
    res.contribution_time = ctx.data.time
    return res


__all__ = ["apply_fits", "fit_effects", "fit_jointly", "holdout_split"]
