"""Compare a model with a measurement log: inverse-dynamics residual, simulation replay, noise floor, and where the
error concentrates.

Two views, both per joint and in total:

- **Inverse-dynamics residual** ``r = tau_J - tau_model(q, dq, ddq)`` on the cleaned log (raw measured torque versus
  the model evaluated on the filtered motion; see :mod:`franka_vs_gym.validation.signals`).
- **Simulation replay**: the MuJoCo plant built from the same configuration re-runs, from the logged initial state,
  either the logged controller (``controller.law == "computed_torque_eq2"`` in the sidecar, with the logged desired
  trajectory), or the logged commanded torques ``tau_J_d`` (open loop), or, when neither is available, eq. (2)
  tracking the measured trajectory (mode ``"tracking"``, which shows the torque the plant needs to reproduce the
  measured motion). RMSE_q (rad) and RMSE_tau (Nm) are reported as in the FrankaSim paper.

The noise floor is the torque-measurement noise estimated from the content above the filter cutoff: no model can
bring the residual RMSE below it.
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np

from franka_vs_gym.model.config import Friction, ModelConfig, Tool, resolve_config
from franka_vs_gym.model.description import robot_description
from franka_vs_gym.validation.evaluate import delay_channel, evaluate, shift
from franka_vs_gym.validation.loading import load_log
from franka_vs_gym.validation.logs import Q_RANGE_WARN, MeasurementLog
from franka_vs_gym.validation.results import CompareResult, ReplayResult, rmse
from franka_vs_gym.validation.signals import CleanSettings, ProcessedLog, clean

VELOCITY_REGIMES = ((0.0, 0.05, "abs(dq) < 0.05 rad/s (near rest: stiction, offsets)"),
                    (0.05, 0.5, "0.05 <= abs(dq) < 0.5 rad/s"),
                    (0.5, math.inf, "abs(dq) >= 0.5 rad/s (viscous regime)"))


class _Progress:
    """The workbench's progress on stderr: one updating line (tqdm), or one line per stage when verbose."""

    bar: Any = None
    verbose: bool = True  # outside progress_line (library use): one line per stage, as printed


def progress(msg: str, enabled: bool = True) -> None:
    """Show a progress stage on stderr (never on stdout, which may carry JSON): on one updating line within
    :func:`progress_line`, else (or with its ``verbose``) as its own line; warnings always get their own line."""
    if not enabled:
        return
    text = f"[franka-vs] {msg}"
    if _Progress.verbose or msg.startswith("warning"):
        if _Progress.bar is not None:
            _Progress.bar.write(text, file=sys.stderr)
        else:
            print(text, file=sys.stderr, flush=True)
        return
    if _Progress.bar is None:
        from tqdm import tqdm

        tqdm.monitor_interval = 0  # the line is updated at each stage: no monitor thread (writers may fork later)
        _Progress.bar = tqdm(total=None, bar_format="{desc} [{elapsed}]", file=sys.stderr, leave=False,
                             dynamic_ncols=True, mininterval=0)
    _Progress.bar.set_description_str(text)


def end_progress() -> None:
    """Clear the progress line (before results are printed)."""
    if _Progress.bar is not None:
        _Progress.bar.close()
        _Progress.bar = None


@contextmanager
def progress_line(verbose: bool = False) -> Iterator[None]:
    """Within: progress on one updating line (``verbose``: one line per stage); cleared on exit."""
    old = _Progress.verbose
    _Progress.verbose = verbose
    try:
        yield
    finally:
        end_progress()
        _Progress.verbose = old


def tool_from_log(log: MeasurementLog) -> Tool:
    """The tool the log declares: the Franka Hand, none, or a custom rigid body."""
    t = log.tool
    if t is None:
        return Tool.none()
    if isinstance(t, str):
        return Tool.from_dict(t)
    return Tool.from_dict({"name": "custom", **t})


TOOLS = ("franka_hand", "none", "unknown")


def estimate_tool(data: ProcessedLog, cfg: ModelConfig) -> tuple[Tool, str]:
    """For a log that declares no tool: whether the Franka Hand (or another mass) is on the flange, from the torques.

    The torque the hand adds (gravity and inertia, the model with the hand minus the model without) is regressed on
    the residual of the model without a tool over up to 4000 samples: the factor ``a`` (the hand-equivalent load,
    1 = the hand's 0.73 kg at its centre of mass) and the RMS residual on joints 1, 3 and 5 (the gravity-loaded
    ones) with and without the hand are the evidence. ``a < 0.5``: no tool; otherwise the hand; outside [0.5, 1.5]
    another mass is likely and said. Returns the tool and one line stating the evidence."""
    idx = np.unique(np.linspace(0, data.n - 1, min(data.n, 4000)).astype(int))
    sub = data.subset(idx)
    bare = cfg.copy(tool=Tool.none())
    hand = cfg.copy(tool=Tool.franka_hand())
    p0 = evaluate(bare, sub).predicted
    p1 = evaluate(hand, sub).predicted
    r0 = sub.tau - p0
    h = p1 - p0
    a = float(np.sum(r0 * h) / max(float(np.sum(h * h)), 1e-12))
    js = [1, 3, 5]
    e0 = float(np.sqrt(np.mean(r0[:, js] ** 2)))
    e1 = float(np.sqrt(np.mean((sub.tau - p1)[:, js] ** 2)))
    mass = hand.tool.body.mass
    evidence = (f"the torques fit a flange load of {a:.2f} x the Franka Hand's ({a * mass:.2f} kg at its centre of "
                f"mass); RMS residual on joints 1, 3, 5: {e0:.3f} Nm without a tool, {e1:.3f} Nm with the hand")
    if a < 0.5:
        chosen, text = Tool.none(), "no tool"
    else:
        chosen, text = Tool.franka_hand(), "the Franka Hand"
    note = (f"not declared by the log: {text} estimated from the data ({evidence})")
    if not 0.5 <= a <= 1.5 and a >= 0.25:
        note += "; another mass is likely on the flange: 'diagnose' names a payload, or use --tool unknown"
    return chosen, note + "; use --tool to say which"


def _other_robot_hint(log: MeasurementLog, cfg: ModelConfig) -> str | None:
    """For a log that does not say which robot it comes from: the registered robots whose joint range holds the
    logged positions when ``cfg``'s robot's does not (e.g. the FR3's sixth joint reaches 4.5 rad, the FER's 3.75)."""
    from franka_vs_gym.model.description import ROBOTS

    def beyond(r) -> float:
        lo, hi = np.asarray(r.limits.q_min, dtype=float), np.asarray(r.limits.q_max, dtype=float)
        return float(np.max(np.maximum(lo - log.q, log.q - hi)))

    if beyond(cfg.robot) <= Q_RANGE_WARN:
        return None
    fits = [r.name for r in ROBOTS.values() if r.name != cfg.robot.name and beyond(r) <= Q_RANGE_WARN]
    if not fits:
        return None
    return (f"the logged positions leave the {cfg.robot.name.upper()}'s joint range by {beyond(cfg.robot):.2f} rad but "
            f"stay within the {', '.join(n.upper() for n in fits)}'s: a log of that robot? (--robot "
            f"{fits[0]})")


#: metadata keys that name the robot of a log, in the order they are read: the workbench's own, then franka_ros's
ROBOT_KEYS = ("robot", "arm_id")


def declared_robot(log: MeasurementLog) -> tuple[str | None, str | None]:
    """``(key, registered name)`` of the robot the log's metadata declares (``robot``, else franka_ros's ``arm_id``;
    a name in words is read by :func:`~franka_vs_gym.model.description.robot_from_words`), ``(None, None)`` when it
    declares none. A declared name that is no registered robot, or names two, raises ValueError naming the key and
    the file (the sidecar), with the flag that overrides it."""
    from franka_vs_gym.model.description import ROBOTS
    from franka_vs_gym.validation.logs import metadata_file

    for key in ROBOT_KEYS:
        v = log.extra.get(key)
        if v is None:
            continue
        where = metadata_file(log)
        if not isinstance(v, str):
            raise ValueError(f"{where}: {key!r} must name the robot in a string (e.g. \"fer\", \"fr3\"), got {v!r}; "
                             f"or pass --robot ({', '.join(sorted(ROBOTS))})")
        try:
            return key, robot_description(v).name
        except ValueError as e:
            why = "names more than one robot" if "ambiguous" in str(e) else "is not a registered robot"
            raise ValueError(f"{where}: {key!r} is {v!r}, which {why}; pass --robot ({', '.join(sorted(ROBOTS))}) "
                             "to say which") from None
    return None, None


def baseline_config(log: MeasurementLog, model: Any = None, rigid_body: bool = False,
                    tool: str | None = None, robot: Any = None, data: ProcessedLog | None = None) -> ModelConfig:
    """The model to start from: ``model`` (a ModelConfig or a calibrated-model file) if given, else the library's
    default FER with the log's declared tool and gravity. ``rigid_body`` removes all friction. ``tool`` overrides
    the tool: "franka_hand", "none", or "unknown" (no tool in the model; ``diagnose`` and ``fit`` then fit the
    tool's mass, centre of mass and inertia as a payload). ``robot`` (a registered name such as "fer" or "fr3", or a
    RobotDescription) chooses the robot; by default the robot the log declares (its sidecar's ``robot``, as
    ``franka-vs serve --record`` writes it), else the FER, with a hint when the logged positions leave the FER's
    joint range but not another robot's. A model file for another robot than the one asked for or declared is an
    error. Where the robot came from is ``notes["robot_source"]``, stated in every output's assumptions. A log that
    declares no tool, given with its processed ``data``, gets the tool :func:`estimate_tool` finds (the evidence in
    the configuration's ``notes["tool_estimate"]``, stated in every output's assumptions)."""
    if tool is not None and tool not in TOOLS:
        raise ValueError(f"unknown --tool {tool!r}: choose from {', '.join(TOOLS)}")
    robot_note = None
    if robot is None:  # e.g. `franka-vs serve --robot fr3 --record` says so, or a lab's sidecar in words
        key, declared = declared_robot(log)
        if declared is not None:
            robot = declared
            robot_note = "declared by the log" + ("" if declared == log.extra.get(key) else
                                                  f" ({key}: {log.extra.get(key)!r})")
    if model is not None:
        try:
            cfg = resolve_config(model, robot)
        except ValueError as e:
            if robot_note is None:
                raise
            raise ValueError(f"{e}: the log was recorded on the {robot} (its sidecar says so); give a model of that "
                             "robot, or --robot to override the log") from None
    else:
        cfg = ModelConfig(robot=robot_description(robot), tool=tool_from_log(log), gravity=log.gravity)
    if (robot_note is None and robot is not None and isinstance(model, ModelConfig)
            and cfg.notes.get("robot_source") and robot_description(robot).name == cfg.robot.name):
        robot_note = cfg.notes["robot_source"]  # a configuration made for this log (fit's inner diagnosis): kept
    if robot_note is None:
        robot_note = ("--robot" if robot is not None else "the model file's" if model is not None else
                      f"not declared by the log: the {cfg.robot.name.upper()} assumed (use --robot to say otherwise)")
        hint = _other_robot_hint(log, cfg) if robot is None and model is None else None
        if hint:
            robot_note += "; " + hint
    cfg = cfg.copy(notes={**cfg.notes, "robot_source": robot_note})
    if model is None:
        if tool is None and not log.tool_declared and data is not None:
            est, note = estimate_tool(data, cfg)
            cfg = cfg.copy(tool=est, notes={**cfg.notes, "tool_estimate": note})
    if tool is not None:
        cfg = cfg.copy(tool=Tool.franka_hand() if tool == "franka_hand" else Tool.none())
    if rigid_body:
        cfg = cfg.copy(friction=Friction.none())
    return cfg


def as_processed(log: MeasurementLog | ProcessedLog | str, settings: CleanSettings | None = None) -> ProcessedLog:
    """Load (path) and clean (MeasurementLog) as needed."""
    if isinstance(log, ProcessedLog):
        return log
    if not isinstance(log, MeasurementLog):
        log = load_log(log)
    return clean(log, settings)


def concentration_table(data: ProcessedLog, residual: np.ndarray, n_windows: int = 10) -> list[dict[str, Any]]:
    """Per joint: RMSE overall, in each velocity regime (share of the squared error and of the samples), and the
    time window (1/n_windows of the log) with the largest RMSE."""
    rows = []
    t = data.time
    edges = np.linspace(0, len(t), n_windows + 1).astype(int)
    for j in range(7):
        r = residual[:, j]
        sq = r ** 2
        total = float(sq.sum()) or 1.0
        row: dict[str, Any] = {"joint": j, "rmse": float(np.sqrt(sq.mean())), "regimes": []}
        a = np.abs(data.dq[:, j])
        for lo, hi, label in VELOCITY_REGIMES:
            m = (a >= lo) & (a < hi)
            row["regimes"].append({"regime": label, "samples": float(m.mean()),
                                   "rmse": float(np.sqrt(sq[m].mean())) if m.any() else None,
                                   "error_share": float(sq[m].sum() / total)})
        w = [float(np.sqrt(sq[edges[k]:edges[k + 1]].mean())) for k in range(n_windows)]
        k = int(np.argmax(w))
        row["worst_window"] = {"t0": float(t[edges[k]]), "t1": float(t[edges[k + 1] - 1]), "rmse": w[k]}
        rows.append(row)
    return rows


class _SteadyEq2:
    """Eq. (2) without the smooth-start term: tau = B (Kp e + Kd de + Ki int e + ddq_d) + C dq [+ F(dq)]."""

    def __init__(self, model, kp, kd, ki, friction: bool) -> None:
        self.m, self.kp, self.kd, self.ki, self.friction = model, kp, kd, ki, friction
        self._int = np.zeros(7)
        self._t: float | None = None

    def __call__(self, t, q, dq, q_d, dq_d, ddq_d):
        e = q_d - q
        if self._t is not None:
            self._int += e * (t - self._t)
        self._t = t
        v = self.kp * e + self.kd * (dq_d - dq) + self.ki * self._int + ddq_d
        tau = self.m.mass_matrix(q) @ v + self.m.coriolis(q, dq)
        return tau + self.m.friction(dq) if self.friction else tau


#: the replay's plant step: about this (s), a whole number of plant steps per log sample; the control laws' gains
#: (eq. (2): 400-900 s^-2) are made for the robot's 1 ms cycle
PLANT_DT = 1e-3
PLANT_DT_SLACK = 0.05  # a log sample period up to 5 % above PLANT_DT is one plant step (a 974 Hz log: 1.03 ms)


def plant_substeps(dt: float) -> int:
    """Plant steps per log sample of period ``dt`` (s): the fewest that keep the plant's step within
    :data:`PLANT_DT_SLACK` of :data:`PLANT_DT` (1 for a 1 kHz log, 10 at 100 Hz, 34 steps of 0.98 ms at 30 Hz)."""
    return max(1, int(math.ceil(dt / PLANT_DT - PLANT_DT_SLACK)))


def hermite_segment(h: float, s: np.ndarray, p0: np.ndarray, v0: np.ndarray, a0: np.ndarray, p1: np.ndarray,
                    v1: np.ndarray, a1: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The quintic Hermite curve between two samples ``h`` seconds apart that passes through their positions with
    their velocities and accelerations, at the fractions ``s`` (m,) of the interval: position, velocity and
    acceleration, each (m, 7). Between samples of a slow log the replay's reference follows it: its position,
    velocity and acceleration agree with each other and with the log at every sample."""
    P = p1 - p0
    V0, V1, A0, A1 = h * v0, h * v1, h * h * a0, h * h * a1
    c = np.stack([p0, V0, 0.5 * A0,
                  10 * P - 6 * V0 - 4 * V1 - 0.5 * (3 * A0 - A1),
                  -15 * P + 8 * V0 + 7 * V1 + 0.5 * (3 * A0 - 2 * A1),
                  6 * P - 3 * (V0 + V1) - 0.5 * (A0 - A1)])  # (6, 7) polynomial coefficients in s
    s = np.asarray(s, dtype=float)[:, None]
    pos = c[0] + s * (c[1] + s * (c[2] + s * (c[3] + s * (c[4] + s * c[5]))))
    vel = c[1] + s * (2 * c[2] + s * (3 * c[3] + s * (4 * c[4] + s * 5 * c[5])))
    acc = 2 * c[2] + s * (6 * c[3] + s * (12 * c[4] + s * 20 * c[5]))
    return pos, vel / h, acc / (h * h)


def replay(data: ProcessedLog, config: ModelConfig, mode: str | None = None) -> ReplayResult:
    """Re-run the logged experiment in the MuJoCo plant built from ``config`` (see the module docstring).

    The plant runs at the robot's own cycle whatever the log's rate: :func:`plant_substeps` steps of about 1 ms per
    log sample (a 30 Hz log: 34 steps of 0.98 ms). Between samples the references (the measured motion in
    ``tracking`` mode, the logged desired motion in ``controller`` mode) follow :func:`hermite_segment` through the
    samples' positions, velocities and accelerations, and logged commands (``torque`` mode) are interpolated
    linearly. The simulated torque and position are taken at the log's samples (the torque of the plant step that
    starts there) and compared with the log there. A 1 kHz log is replayed one plant step per sample, as before."""
    from franka_vs_gym.control.computed_torque import ComputedTorque
    from franka_vs_gym.model.franka_model import FrankaModel
    from franka_vs_gym.sim.reflexes import ControlException
    from franka_vs_gym.sim.robot import FORCE_TORQUE, JOINT_STATE, FrankaSim, SimulationDiverged

    log = data.log
    ctrl_meta = log.controller or {}
    opt = data.optional
    has_ctrl = ctrl_meta.get("law") == "computed_torque_eq2" and all(k in opt for k in ("q_d", "dq_d", "ddq_d"))
    if mode is None:
        mode = "controller" if has_ctrl else ("torque" if "tau_J_d" in opt else "tracking")
    if mode == "controller" and not has_ctrl:
        raise ValueError("replay mode 'controller' needs controller.law = 'computed_torque_eq2' in the sidecar and "
                         "q_d, dq_d, ddq_d columns")
    if mode == "torque" and "tau_J_d" not in opt:
        raise ValueError("replay mode 'torque' needs tau_J_d columns in the log")
    # a delay of the "command" channel is the plant's own (commands reach the joints late); a "measurement" delay
    # (tau_J lags the motion) is not a property of the plant: it runs without it and the simulated torque
    # measurement is shifted afterwards.
    # A payload in the configuration is a body the robot did not know about while logging (its gravity
    # compensation used the declared tool only): it enters the plant as an undeclared body.
    measured_lag = config.delay if delay_channel(config) == "measurement" else 0.0
    # Commanded torques pass through the robot's motors (its effective armature, RobotDescription.rotor_inertia)
    # before they reach the links: a "torque" replay drives a plant with them, as the robot (real, or franka-vs
    # serve, whose own recordings state the values they had). Controller and tracking replays are unchanged.
    rotor = ctrl_meta.get("rotor_inertia_kgm2")
    if rotor is None and mode == "torque":
        rotor = list(config.robot.rotor_inertia)
    plant_config = config.copy(delay=config.delay - measured_lag, payload=None)
    if rotor is not None:
        from dataclasses import replace as _replace

        plant_config = plant_config.copy(robot=_replace(config.robot, rotor_inertia=tuple(float(v) for v in rotor)))
    n_sub = plant_substeps(data.dt)
    sim = FrankaSim(model=plant_config, camera=False, table=False, timestep=data.dt / n_sub,
                    undeclared_payload=config.payload, rotor_inertia=rotor is not None)
    lim_lo, lim_hi = sim.q_min + 1e-6, sim.q_max - 1e-6
    start = 0
    if mode == "controller":
        # eq. (2)'s smooth start (tau0 exp(-mu t)) cannot be re-run from a state in the middle of the transient:
        # the replay starts once the transient has decayed (5 / mu after the log's start) with mu = 0
        mu = float(ctrl_meta.get("mu") if ctrl_meta.get("mu") is not None else 4.0)
        t_abs = data.time  # seconds since the log's first sample
        if mu > 0:
            later = np.nonzero(t_abs >= 5.0 / mu)[0]
            if len(later) and later[0] < data.n - 100:
                start = int(later[0])
    sim.reset(np.clip(data.q[start], lim_lo, lim_hi), data.dq[start])
    sim.set_robot_state(FORCE_TORQUE)
    n = data.n
    q_sim = np.full((n, 7), np.nan)
    tau_sim = np.full((n, 7), np.nan)
    if mode == "controller":
        ctrl_cfg = ctrl_meta.get("model")
        cmodel = FrankaModel(ModelConfig.from_dict(ctrl_cfg) if isinstance(ctrl_cfg, dict) else
                             baseline_config(log, robot=config.robot))
        # the gains and model of the logged eq. (2); the smooth start is over, so its term is left out
        ki = ctrl_meta.get("ki")
        ref = ComputedTorque(cmodel, kp=ctrl_meta.get("kp"), kd=ctrl_meta.get("kd"), ki=0.0 if ki is None else ki)
        # friction compensation: "friction": false, or the tracking experiment's "model_error": "no-friction"
        comp = ctrl_meta.get("friction", ctrl_meta.get("model_error") != "no-friction")
        law = _SteadyEq2(cmodel, ref.kp, ref.kd, ref.ki, bool(comp))
        qd, dqd, ddqd = opt["q_d"], opt["dq_d"], opt["ddq_d"]
    elif mode == "tracking":
        ref = ComputedTorque(FrankaModel(config))
        law = _SteadyEq2(FrankaModel(config), ref.kp, ref.kd, ref.ki, True)
        qd, dqd, ddqd = data.q, data.dq, data.ddq
    diverged = None
    stop: dict[str, Any] | None = None
    t = data.time
    k = start
    frac = np.arange(n_sub) / n_sub  # the plant steps' starts within a log sample's interval
    try:
        for k in range(start, n):
            last = k == n - 1 or n_sub == 1
            if mode == "torque":
                cmds = (opt["tau_J_d"][k][None] if last else
                        opt["tau_J_d"][k] + frac[:, None] * (opt["tau_J_d"][k + 1] - opt["tau_J_d"][k]))
            elif last:
                ref = (qd[k][None], dqd[k][None], ddqd[k][None])
            else:
                ref = hermite_segment(float(t[k + 1] - t[k]), frac, qd[k], dqd[k], ddqd[k], qd[k + 1], dqd[k + 1],
                                      ddqd[k + 1])
            for i in range(1 if last else n_sub):
                q, dq = sim.get_position(), sim.get_velocity()
                if i == 0:
                    q_sim[k] = q
                if mode == "torque":
                    cmd = cmds[i]
                else:
                    cmd = law(float(t[k]) + frac[i] * data.dt, q, dq, ref[0][i], ref[1][i], ref[2][i])
                sim.set_force_torque(JOINT_STATE, cmd)
                sim.step()
                if i == 0:
                    tau_sim[k] = sim.get_force_torque()
    except (SimulationDiverged, ControlException, ValueError) as e:
        # diverged, a reflex aborted the motion (as libfranka would), or the plant refused a state or command (e.g.
        # outside the joint limits): reported with the mode, time and joint, the samples before kept
        what = ("diverged" if isinstance(e, SimulationDiverged) else
                "reflex" if isinstance(e, ControlException) else "refused")
        diverged = f"{'diverged' if what == 'diverged' else 'stopped'} at t = {t[k]:.3f} s: {e}"
        m = re.search(r"joint (\d)", str(e))
        tm = re.search(r"t=([0-9.eE+-]+) s", str(e))  # the violation's own time in the plant (reset at t[start])
        when = float(t[start]) + float(tm.group(1)) if tm else float(t[k])
        stop = {"mode": mode, "time_s": round(when, 4), "joint": int(m.group(1)) if m else None,
                "kind": what, "reason": " ".join(str(e).split())}
        q_sim[k:] = np.nan
        tau_sim[k:] = np.nan
    if measured_lag > 0:
        tau_sim[start:] = shift(tau_sim[start:], t[start:], measured_lag)
    ok = np.isfinite(q_sim[:, 0]) & np.isfinite(tau_sim[:, 0])
    if not ok.any():  # stopped at its first sample: nothing to compare
        return ReplayResult(mode, np.full(7, np.nan), np.full(7, np.nan), q_sim, tau_sim, diverged, stop,
                            plant_dt=sim.dt)
    return ReplayResult(mode, rmse(q_sim[ok] - data.q[ok]), rmse(tau_sim[ok] - data.tau[ok]), q_sim, tau_sim,
                        diverged, stop, plant_dt=sim.dt)


def replay_with_fallback(data: ProcessedLog, config: ModelConfig, mode: str | None = None) -> ReplayResult:
    """:func:`replay`; when that replay stops before the end of the log (a reflex, a divergence, a refused state) in
    a mode other than tracking, the log is replayed again in ``tracking`` mode (eq. (2) following the measured
    motion, which can run on any log), and the result says which replay stopped where and why
    (``fallback_from``, :meth:`ReplayResult.status`)."""
    first = replay(data, config, mode)
    if first.stop is None or first.mode == "tracking":
        return first
    second = replay(data, config, "tracking")
    second.fallback_from = [first.stop]
    return second


def compare(log: MeasurementLog | ProcessedLog | str, model: Any = None, *, rigid_body: bool = False,
            settings: CleanSettings | None = None, do_replay: bool = True, replay_mode: str | None = None,
            verbose: bool = False, tool: str | None = None, robot: Any = None) -> CompareResult:
    """Compare ``model`` (default: the baseline for the log, see :func:`baseline_config`) with a log."""
    progress("cleaning the log", verbose)
    data = as_processed(log, settings)
    cfg = baseline_config(data.log, model, rigid_body, tool=tool, robot=robot, data=data)
    progress(f"inverse dynamics on {data.n} samples", verbose)
    ev = evaluate(cfg, data)
    r = data.tau - ev.predicted
    res = CompareResult(cfg, data, ev, r, rmse(r), float(np.sqrt(np.mean(r ** 2))), r.mean(axis=0),
                        np.abs(r).max(axis=0), data.noise.copy(), concentration_table(data, r))
    if do_replay:
        progress("simulation replay in the MuJoCo plant", verbose)
        res.replay = replay_with_fallback(data, cfg, replay_mode)
        if res.replay.fallback_from or res.replay.stop:
            progress(f"replay: {res.replay.status()}", verbose)
    return res


def format_compare(res: CompareResult) -> str:
    """A plain-text summary table (per joint RMSE, bias, noise floor, replay)."""
    lines = ["joint   rmse_tau  mean_tau  noise_floor  worst window (s)        largest error share"]
    for j, row in enumerate(res.concentration):
        reg = max(row["regimes"], key=lambda x: x["error_share"])
        w = row["worst_window"]
        lines.append(f"{j:5d}  {res.rmse_tau[j]:8.3f}  {res.mean_tau[j]:8.3f}  {res.noise_floor[j]:11.3f}  "
                     f"{w['t0']:6.1f}-{w['t1']:6.1f} ({w['rmse']:.3f})   {reg['error_share'] * 100:4.0f}% in "
                     f"{reg['regime']}")
    lines.append(f"total  {res.rmse_tau_total:8.3f}  (Nm)")
    a = res.assumptions()
    lines.append(f"assumptions: tool {a['tool']} ({a['tool_source']}), gravity {a['gravity_m_per_s2']} m/s^2, log "
                 f"rate {a['log_rate_hz']} Hz, processed at {a['resampled_to_hz']:g} Hz, low-pass "
                 f"{a['cleaning']['lowpass_hz']:g} Hz, {a['cleaning']['stale_rows_dropped']} stale rows dropped")
    if a.get("log_read_as"):
        lines.append(f"log read as: {a['log_read_as']}")
    lines += [f"warning: {w}" for w in a["warnings"]]
    if res.replay is not None:
        rp = res.replay
        lines.append(f"replay ({rp.mode}): RMSE_q = {np.round(rp.rmse_q, 4).tolist()} rad")
        lines.append(f"                   RMSE_tau = {np.round(rp.rmse_tau, 3).tolist()} Nm")
        if rp.fallback_from or rp.stop:
            lines.append(f"replay status: {rp.status()}")
    return "\n".join(lines)


__all__ = ["CompareResult", "ReplayResult", "as_processed", "baseline_config", "compare", "concentration_table",
           "end_progress", "format_compare", "progress", "progress_line", "replay", "replay_with_fallback", "rmse",
           "tool_from_log", "declared_robot"]
