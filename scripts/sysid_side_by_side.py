"""The workbench side by side with MuJoCo's own system identification (``mujoco.sysid``, shipped with mujoco).

Both fit the same physical parameters to the same torque log, on the first 75 % of it, and predict the last 25 %:

- **workbench**: the joint linear least-squares fit of the effects (``validation.selection.Engine``) with the
  intervals of ``validation.uncertainty`` (HAC sandwich, delta method);
- **mujoco.sysid**: its ``Parameter`` / ``ParameterDict``, its optimiser (``mujoco.sysid.optimize``, scipy backend)
  and its intervals (``mujoco.sysid.calculate_intervals``: ``s^2 (J^T J)^-1`` with a Student quantile, infinite
  where an eigen-direction is null). The residual it minimises is MuJoCo's own inverse dynamics: the logged
  torque's baseline residual minus the change of ``mj_inverse`` when the parameters are written into the MuJoCo
  model of the FER (``dof_damping`` = viscous friction, ``dof_armature`` = armature, a body welded to link 7 =
  payload mass and centre of mass).

Logs: ``A`` (tests/independent_logs.py: analytic, open loop, white noise), ``H`` (validation.hidden: the MuJoCo
plant under computed-torque control, a closed loop), ``Gaz`` (the real FER log of Gaz et al. 2019, no truth).
Prints a Markdown table: held-out RMSE, median interval half-width, coverage of the truth, wall time.

**Closed loop, fitted by replay** (``--closed-loop N``): a joint impedance law (libfranka's example gains) runs on
the measured state of a MuJoCo plant with hidden joint damping and armature (``closed_loop_log``). There
``mujoco.sysid`` does what it is made for: its rollout (``sysid_rollout`` inside its ``residual``) replays the closed
loop on the model with candidate parameters written into the ``MjSpec`` by its ``Parameter`` modifiers, and its
optimiser fits the measured joint positions of the first 75 %; the workbench fits the same two effects to the
torque by inverse dynamics. Each one's parameters are then judged by both criteria on the last 25 %: the
inverse-dynamics torque RMSE and the replay RMSE of the joint positions (the loop closed on the model, started from
the measured state), with interval widths, coverage of the truth and wall time (a second table).

Usage: python scripts/sysid_side_by_side.py [--gaz /work/shared/data/gaz2019_traj1] [--seeds 2] [--closed-loop 2]
       [--only-closed-loop]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import sys
import time
from pathlib import Path

import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))


def mujoco_model():
    """The FER with the Franka Hand as the simulator builds it, plus a massless body at link 7's origin whose mass
    and centre of mass stand for a payload."""
    from franka_vs_gym.assets.mjcf import SceneSpec, scene_xml

    spec = mujoco.MjSpec.from_string(scene_xml(SceneSpec(table=False)))
    link7 = spec.body("r0_link7")
    link7.add_body(name="sysid_payload", pos=[0, 0, 0], mass=1e-9, ipos=[0, 0, 0.107],
                   inertia=[1e-9, 1e-9, 1e-9], explicitinertial=True)
    m = spec.compile()
    return m, mujoco.MjData(m), m.body("sysid_payload").id


class MujocoInverse:
    """tau = mj_inverse(q, dq, ddq) on the samples of a processed log, for parameter values written into the
    model (returns the change from the nominal model, (n, 7))."""

    def __init__(self, data, idx: np.ndarray) -> None:
        self.m, self.d, self.pid = mujoco_model()
        self.q, self.dq, self.ddq = data.q[idx], data.dq[idx], data.ddq[idx]
        self.nominal = self.run({})

    def run(self, p: dict) -> np.ndarray:
        m, d = self.m, self.d
        m.dof_damping[:7] = p.get("damping", np.zeros(7))
        m.dof_armature[:7] = p.get("armature", np.zeros(7))
        m.body_mass[self.pid] = float(np.ravel(p.get("mass", 1e-9))[0])
        m.body_ipos[self.pid] = p.get("com7", np.array([0, 0, 0.107]))
        out = np.empty((len(self.q), 7))
        for k in range(len(self.q)):
            d.qpos[:7], d.qvel[:7], d.qacc[:7] = self.q[k], self.dq[k], self.ddq[k]
            mujoco.mj_inverse(m, d)
            out[k] = d.qfrc_inverse[:7]
        return out if not hasattr(self, "nominal") else out - self.nominal


PARAMS = {"viscous_friction": ("damping", 7, 0.0, 0.0, 5.0), "armature": ("armature", 7, 0.0, 0.0, 2.0),
          "payload": ("mass", 1, 0.5, 0.0, 5.0)}


def sysid_fit(data, y: np.ndarray, train: np.ndarray, test: np.ndarray, effects: list[str]):
    """mujoco.sysid on the residual y (n, 7): parameters, their interval half-widths, held-out RMSE, seconds."""
    from mujoco import sysid

    t0 = time.perf_counter()
    pd = sysid.ParameterDict()
    for e in effects:
        name, n, nom, lo, hi = PARAMS[e]
        pd.add(sysid.Parameter(name, np.full(n, nom), np.full(n, lo), np.full(n, hi)))
        if e == "payload":
            pd.add(sysid.Parameter("com7", np.array([0.0, 0.0, 0.15]), np.array([-0.3, -0.3, -0.2]),
                                   np.array([0.3, 0.3, 0.5])))
    inv = MujocoInverse(data, train)
    w = 1.0 / np.maximum(np.asarray(data.noise), 1e-3)  # each joint weighted by its noise floor

    def values(params) -> dict:
        return {k: params[k].value for k in params.keys()}

    def residual_fn(x, params):
        params.update_from_vector(x)
        r = (y[train] - inv.run(values(params))) * w
        return [r.ravel()], None, None

    with contextlib.redirect_stdout(io.StringIO()):  # its scipy backend prints every iteration
        opt, res = sysid.optimize(pd, residual_fn, optimizer="scipy", verbose=False, max_iters=60)
    r_star = residual_fn(res.x, opt)[0]
    _, half = sysid.calculate_intervals(r_star, res.jac)
    secs = time.perf_counter() - t0
    inv_test = MujocoInverse(data, test)
    pred = inv_test.run(values(opt))
    rmse = float(np.sqrt(np.mean((y[test] - pred) ** 2)))
    names = [f"{k}[{i}]" for k in opt.keys() for i in range(opt[k].size)]
    return dict(zip(names, res.x, strict=True)), dict(zip(names, half, strict=True)), rmse, secs


def workbench_fit(ctx, y: np.ndarray, train: np.ndarray, test: np.ndarray, effects: list[str]):
    """The workbench on the same residual: joint least squares on the training samples, intervals, held-out RMSE."""
    from franka_vs_gym.validation.effects import get_effect
    from franka_vs_gym.validation.selection import Engine, Term
    from franka_vs_gym.validation.uncertainty import confidence

    t0 = time.perf_counter()
    es = [get_effect(e) for e in effects]
    eng = Engine(ctx, y, [train])
    terms = [Term(e, e.shape(ctx, y), list(range(7)) if e.per_joint else None) for e in es]
    sf = eng.fit(terms, cv=False)
    yt = np.zeros_like(y)
    yt[train] = y[train]  # the intervals from the training samples' residual only
    sub = ctx.data.subset(train)
    from franka_vs_gym.validation.effects import Context

    ctx_t = Context(sub, ctx.config)
    conf = confidence(ctx_t, es, sf.fits, y[train])
    secs = time.perf_counter() - t0
    pred = sum((e.contribution(ctx, f) for e, f in zip(es, sf.fits, strict=True)), np.zeros_like(y))
    rmse = float(np.sqrt(np.mean((y[test] - pred[test]) ** 2)))
    params = {e.name: e.public(f) for e, f in zip(es, sf.fits, strict=True)}
    return params, dict(zip([e.name for e in es], conf.params_ci95, strict=True)), rmse, secs


def _inside(ci, t) -> tuple[int, int]:
    return (int(ci[0] <= t <= ci[1]), 1) if ci is not None else (0, 1)


def compare_case(label: str, log, effects: list[str], truth: dict | None) -> dict:
    from franka_vs_gym.validation.compare import as_processed, baseline_config
    from franka_vs_gym.validation.effects import Context
    from franka_vs_gym.validation.fitting import holdout_split

    data = as_processed(log)
    ctx = Context(data, baseline_config(data.log, None, False))
    y = ctx.residual
    train, test = holdout_split(ctx.n)
    wp, wci, wr, ws = workbench_fit(ctx, y, train, test, effects)
    sp, shalf, sr, ss = sysid_fit(data, y, train, test, effects)
    row = {"case": label, "effects": effects, "rmse_baseline": float(np.sqrt(np.mean(y[test] ** 2))),
           "rmse_workbench": wr, "rmse_sysid": sr, "s_workbench": ws, "s_sysid": ss, "cover_w": [0, 0],
           "cover_s": [0, 0], "hw_w": [], "hw_s": []}
    keys = {"viscous_friction": ("viscous_Nms_per_rad", "damping"), "armature": ("armature_kgm2", "armature"),
            "payload": ("mass_kg", "mass")}
    for e in effects:
        wk, sk = keys[e]
        wc = wci[e][wk] if isinstance(wp[e][wk], list) else [wci[e][wk]]
        for i, c in enumerate(wc):
            sv, sh = sp[f"{sk}[{i}]"], shalf[f"{sk}[{i}]"]
            if c is not None:
                row["hw_w"].append((c[1] - c[0]) / 2)
            row["hw_s"].append(sh)
            if truth is not None and e in truth:
                t = truth[e][i] if isinstance(truth[e], list) else truth[e]
                a, n = _inside(c, t)
                row["cover_w"][0] += a
                row["cover_w"][1] += n
                row["cover_s"][0] += int(abs(sv - t) <= sh)
                row["cover_s"][1] += 1
    return row


def coloured(log, seed: int, rho: float = 0.998, sd: float = 0.15):
    """The log with a slowly wandering torque error (AR(1) at 1 kHz, time constant 0.5 s; 0.15 Nm on joints 0-3,
    less on the wrist), the kind of coloured error a real torque sensor and an imperfect model leave."""
    from dataclasses import replace

    rng = np.random.default_rng(1000 + seed)
    n = len(log.time)
    e = np.zeros((n, 7))
    w = rng.normal(0, sd * np.sqrt(1 - rho ** 2), (n, 7))
    e[0] = rng.normal(0, sd, 7)
    for k in range(1, n):
        e[k] = rho * e[k - 1] + w[k]
    return replace(log, tau_J=log.tau_J + e * np.array([1, 1, 1, 1, 0.4, 0.4, 0.2]))


# --------------------------------------------------------------------------- the closed-loop case: a replay fit
# joint impedance gains of libfranka's joint_impedance_control example (k_gains, d_gains)
KP = np.array([600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0])
KD = np.array([50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0])
JOINTS = [f"r0_joint{i}" for i in range(1, 8)]


def impedance_spec() -> mujoco.MjSpec:
    """The FER + Franka Hand as the simulator builds it (with its gravity compensation of the arm's bodies, the
    robot's own, as libfranka's torque interface has), its actuators replaced by a joint impedance law in MuJoCo's
    own terms: ``kp (ctrl_q - q)`` and ``kd (ctrl_dq - dq)`` per joint (controls: q_d, then dq_d), semi-implicit
    Euler (joint damping implicit, actuator forces explicit, as a 1 kHz controller applies them)."""
    from franka_vs_gym.assets.mjcf import SceneSpec, scene_xml

    spec = mujoco.MjSpec.from_string(scene_xml(SceneSpec(table=False)))
    # explicit actuator forces: with the implicit integrator the law's damping kd would act on the next step's
    # velocity, i.e. as an extra inertia dt kd (0.015-0.05 kg m^2) in the logged torque-acceleration relation
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    for a in list(spec.actuators):
        spec.delete(a)
    for gains, col in ((KP, 1), (KD, 2)):
        for j, name in enumerate(JOINTS):
            a = spec.add_actuator(name=f"{'kp' if col == 1 else 'kd'}{j + 1}", target=name,
                                  trntype=mujoco.mjtTrn.mjTRN_JOINT)
            a.gaintype, a.biastype = mujoco.mjtGain.mjGAIN_FIXED, mujoco.mjtBias.mjBIAS_AFFINE
            a.gainprm[0], a.biasprm[col] = gains[j], -gains[j]
            a.ctrllimited = a.forcelimited = 0
    return spec


def _write(spec: mujoco.MjSpec, damping: np.ndarray, armature: np.ndarray) -> mujoco.MjSpec:
    for j, name in enumerate(JOINTS):
        spec.joint(name).damping = [float(damping[j]), 0.0, 0.0]  # MuJoCo 4: (linear, quadratic, cubic)
        spec.joint(name).armature = float(armature[j])
    return spec


def closed_loop_log(seed: int, duration: float = 8.0, noise: float = 1.0):
    """A closed-loop log with known truth: the plant (``impedance_spec`` with hidden joint damping and armature, the
    sizes ``validation.hidden`` injects) under the joint impedance law computed on the *measured* state (the sensor
    noise of ``validation.hidden`` enters the loop), tracking the exciting trajectory of ``validation.hidden``.
    Logged as a robot logs: q, dq (noisy), tau_J = the joints' drive torque (impedance + gravity compensation,
    the mean of the torques before and after the row's instant) with torque-sensor noise, q_d, dq_d, ddq_d and the
    command (``noise`` scales every noise). Returns ``(log, {"damping": (7,), "armature": (7,)})``."""
    from franka_vs_gym.validation.hidden import DQ_NOISE, Q_NOISE, TORQUE_NOISE, fourier_trajectory
    from franka_vs_gym.validation.logs import MeasurementLog

    rng = np.random.default_rng(500 + seed)
    damping = np.array([0.5, 0.5, 0.4, 0.4, 0.15, 0.15, 0.08]) * rng.uniform(0.7, 1.3, 7)
    armature = np.array([0.25, 0.25, 0.2, 0.2, 0.06, 0.06, 0.03]) * rng.uniform(0.7, 1.3, 7)
    m = _write(impedance_spec(), damping, armature).compile()
    d = mujoco.MjData(m)
    traj = fourier_trajectory(rng, duration)
    n = int(round(duration / m.opt.timestep))
    t = np.arange(n) * m.opt.timestep
    ref = np.array([np.concatenate(traj(tk)) for tk in t])
    qd, dqd, ddqd = ref[:, :7], ref[:, 7:14], ref[:, 14:]
    d.qpos[:7], d.qvel[:7] = qd[0], dqd[0]
    q, dq, tau, cmd = (np.empty((n, 7)) for _ in range(4))
    sig = TORQUE_NOISE * rng.uniform(0.8, 1.2, 7)
    for k in range(n):
        nq, ndq = rng.normal(0, Q_NOISE * noise, 7), rng.normal(0, DQ_NOISE * noise, 7)
        q[k], dq[k] = d.qpos[:7] + nq, d.qvel[:7] + ndq
        d.ctrl[:7], d.ctrl[7:] = qd[k] - nq, dqd[k] - ndq  # kp (q_d - q_meas), kd (dq_d - dq_meas)
        mujoco.mj_step(m, d)
        tau[k] = d.qfrc_actuator[:7]  # the arm's gravity compensation is routed through the actuators
        cmd[k] = tau[k] - d.qfrc_gravcomp[:7]  # the command without it, as libfranka's tau_J_d
    tau[1:] = 0.5 * (tau[1:] + tau[:-1])
    log = MeasurementLog(t, q, dq, tau + rng.normal(0, 1, (n, 7)) * sig * noise, tau_J_d=cmd, q_d=qd, dq_d=dqd,
                         ddq_d=ddqd, tool="franka_hand",
                         controller={"law": "joint_impedance", "kp": KP.tolist(), "kd": KD.tolist()},
                         extra={"generator": "scripts/sysid_side_by_side.py closed_loop_log"})
    return log, {"damping": damping, "armature": armature}


def _sequences(log, idx: np.ndarray, name: str):
    """mujoco.sysid's ModelSequences for the samples ``idx`` of the log: control (q_d, dq_d), the measured joint
    positions as state observations (a rollout's state row i is the state after step i, stamped t_i + dt: it lines
    up with the measured row of that time; its sensor rows are the state before the step), the first measured state
    as initial state."""
    from mujoco import sysid

    spec = impedance_spec()
    m = spec.compile()
    t = log.time[idx] - log.time[idx[0]]
    ctrl = sysid.TimeSeries.from_control_names(t, np.hstack([log.q_d[idx], log.dq_d[idx]]), m)
    meas = sysid.TimeSeries.from_names(t, log.q[idx], m, [(j, sysid.SignalType.MjStateQPos) for j in JOINTS])
    x0 = sysid.create_initial_state(m, log.q[idx[0]], log.dq[idx[0]])
    return sysid.ModelSequences(name, spec, name, x0, ctrl, meas, allow_missing_sensors=True)


def replay_rmse(log, idx: np.ndarray, damping: np.ndarray, armature: np.ndarray) -> float:
    """RMS (rad) of measured minus replayed joint positions over ``idx``: the impedance law closed on the model with
    these parameters (``mujoco.sysid.sysid_rollout``), started from the measured state."""
    from mujoco import sysid

    seq = _sequences(log, idx, "replay")
    # MuJoCo needs damping and armature >= 0: a negative fitted change is replayed as 0
    m = _write(impedance_spec(), np.maximum(damping, 0.0), np.maximum(armature, 0.0)).compile()
    tr = sysid.sysid_rollout(m, mujoco.MjData(m), seq.control[0], seq.initial_state[0])[0]
    qs = tr.state.data[:, 1:8]  # state after each step
    return float(np.sqrt(np.mean((qs - log.q[idx][1:len(qs) + 1]) ** 2)))


def sysid_replay_fit(log, train: np.ndarray, max_iters: int = 30):
    """mujoco.sysid fitting joint damping and armature to the closed-loop replay error of the training samples:
    its Parameter modifiers write them into the MjSpec, its residual rolls the impedance loop out and compares the
    joint positions, its scipy optimiser and calculate_intervals. Returns (damping, armature, half-widths (14,),
    seconds)."""
    from mujoco import sysid

    t0 = time.perf_counter()

    def modifier(attr):
        def mod(spec, p):
            for j, name in enumerate(JOINTS):
                if attr == "damping":
                    spec.joint(name).damping = [float(p.value[j]), 0.0, 0.0]
                else:
                    spec.joint(name).armature = float(p.value[j])
        return mod

    pd = sysid.ParameterDict()
    pd.add(sysid.Parameter("damping", np.full(7, 0.05), np.zeros(7), np.full(7, 5.0), modifier=modifier("damping")))
    pd.add(sysid.Parameter("armature", np.full(7, 0.05), np.zeros(7), np.full(7, 2.0),
                           modifier=modifier("armature")))
    fn = sysid.build_residual_fn(models_sequences=[_sequences(log, train, "train")])
    with contextlib.redirect_stdout(io.StringIO()):  # its scipy backend prints every iteration
        opt, res = sysid.optimize(pd, fn, optimizer="scipy", verbose=False, max_iters=max_iters)
    r_star = fn(res.x, opt)[0]
    _, half = sysid.calculate_intervals(r_star, res.jac)
    return opt["damping"].value.copy(), opt["armature"].value.copy(), np.asarray(half), time.perf_counter() - t0


def closed_loop_case(seed: int, duration: float) -> dict:
    """Both fits on one closed-loop log: each one's parameters judged by both criteria (held-out torque RMSE of the
    inverse dynamics, held-out replay RMSE of the joint positions), interval widths, coverage, wall time."""
    from franka_vs_gym.validation.compare import as_processed, baseline_config
    from franka_vs_gym.validation.effects import Context
    from franka_vs_gym.validation.fitting import holdout_split

    log, truth = closed_loop_log(seed, duration)
    data = as_processed(log)
    ctx = Context(data, baseline_config(data.log, None, True))  # the plant has no joint friction: rigid body
    y = ctx.residual
    train, test = holdout_split(ctx.n)
    wp, wci, _, ws = workbench_fit(ctx, y, train, test, ["viscous_friction", "armature"])
    w_b = np.array(wp["viscous_friction"]["viscous_Nms_per_rad"])
    w_i = np.array(wp["armature"]["armature_kgm2"])
    w_ci = [wci["viscous_friction"]["viscous_Nms_per_rad"], wci["armature"]["armature_kgm2"]]
    # the raw log's samples of the processed log's training / test spans (processing trims and resamples)
    t_split = data.time[test[0]] + (log.time[0] + data.settings.trim)
    raw_train = np.nonzero(log.time < t_split)[0]
    raw_test = np.nonzero(log.time >= t_split)[0]
    s_b, s_i, half, ss = sysid_replay_fit(log, raw_train)
    row = {"case": f"closed loop seed {seed} (joint impedance, MuJoCo plant)", "s_workbench": ws, "s_sysid": ss}

    def torque_rmse(b, i):
        return float(np.sqrt(np.mean((y[test] - data.dq[test] * b - data.ddq[test] * i) ** 2)))

    z = np.zeros(7)
    row["torque"] = [torque_rmse(z, z), torque_rmse(w_b, w_i), torque_rmse(s_b, s_i)]
    row["replay"] = [replay_rmse(log, raw_test, z, z), replay_rmse(log, raw_test, w_b, w_i),
                     replay_rmse(log, raw_test, s_b, s_i)]
    tv = np.concatenate([truth["damping"], truth["armature"]])
    wv = [c for cc in w_ci for c in cc]
    row["hw_w"] = [(c[1] - c[0]) / 2 for c in wv if c is not None]
    row["hw_s"] = list(half)
    row["cover_w"] = [sum(int(c is not None and c[0] <= t <= c[1]) for c, t in zip(wv, tv, strict=True)), 14]
    sv = np.concatenate([s_b, s_i])
    row["cover_s"] = [int(np.sum(np.abs(sv - tv) <= half)), 14]
    row["err_w"] = float(np.median(np.abs(np.concatenate([w_b, w_i]) - tv) / tv))
    row["err_s"] = float(np.median(np.abs(sv - tv) / tv))
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, default=2)
    p.add_argument("--duration", type=float, default=8.0)
    p.add_argument("--gaz", default=None, help="the Gaz et al. 2019 log folder (optional)")
    p.add_argument("--closed-loop", type=int, default=2, help="closed-loop logs (seeds 0..N-1) for the replay fit")
    p.add_argument("--only-closed-loop", action="store_true", help="skip the inverse-dynamics logs")
    args = p.parse_args(argv)
    from absl import logging as absl_logging

    absl_logging.set_verbosity(absl_logging.ERROR)  # mujoco.sysid warns that the model has no sensors (by design)
    import independent_logs as ga

    from franka_vs_gym.validation.hidden import make_hidden_effect_log

    rows = []
    for s in range(0 if args.only_closed_loop else args.seeds):
        log, t = ga.make_log(["viscous", "payload"], s, duration=args.duration)
        tr = {"viscous_friction": t["params"]["viscous"]["b"], "payload": t["params"]["payload"]["mass"]}
        rows.append(compare_case(f"A seed {s} (open loop, white noise)", log, ["viscous_friction", "payload"], tr))
        print(rows[-1], file=sys.stderr)
        rows.append(compare_case(f"A seed {s} + coloured torque error", coloured(log, s), ["viscous_friction",
                                                                                          "payload"], tr))
        print(rows[-1], file=sys.stderr)
        log, ans = make_hidden_effect_log("payload+armature", s, duration=args.duration)
        tr = {"armature": ans["params"]["armature"]["armature_kgm2"], "payload": ans["params"]["payload"]["mass_kg"]}
        rows.append(compare_case(f"H seed {s} (closed loop, MuJoCo plant)", log, ["armature", "payload"], tr))
        print(rows[-1], file=sys.stderr)
    if args.gaz and not args.only_closed_loop:
        from franka_vs_gym.validation.loading import load_log

        rows.append(compare_case("Gaz 2019 traj. 1 (real FER)", load_log(args.gaz), ["viscous_friction", "armature"],
                                 None))
        print(rows[-1], file=sys.stderr)
    print("| log | parameters | held-out RMSE (Nm): baseline / workbench / sysid | median 95% half-width: workbench "
          "/ sysid | truth covered: workbench / sysid | wall s: workbench / sysid |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        cw = f"{r['cover_w'][0]}/{r['cover_w'][1]}" if r["cover_w"][1] else "-"
        cs = f"{r['cover_s'][0]}/{r['cover_s'][1]}" if r["cover_s"][1] else "-"
        print(f"| {r['case']} | {' + '.join(r['effects'])} | {r['rmse_baseline']:.4f} / {r['rmse_workbench']:.4f} / "
              f"{r['rmse_sysid']:.4f} | {np.median(r['hw_w']):.3g} / {np.median(r['hw_s']):.3g} | {cw} / {cs} | "
              f"{r['s_workbench']:.2f} / {r['s_sysid']:.2f} |")
    cl = [closed_loop_case(s, args.duration) for s in range(args.closed_loop)]
    if cl:
        print("\n| closed-loop log | held-out torque RMSE (Nm): baseline / workbench / sysid | held-out replay RMSE "
              "(mrad): baseline / workbench / sysid | median 95% half-width: workbench / sysid | truth covered: "
              "workbench / sysid | median error vs truth: workbench / sysid | wall s: workbench / sysid |")
        print("|---|---|---|---|---|---|---|")
    for r in cl:
        print(f"| {r['case']} | {' / '.join(f'{v:.4f}' for v in r['torque'])} | "
              f"{' / '.join(f'{1e3 * v:.4f}' for v in r['replay'])} | {np.median(r['hw_w']):.3g} / "
              f"{np.median(r['hw_s']):.3g} | {r['cover_w'][0]}/{r['cover_w'][1]} / {r['cover_s'][0]}/"
              f"{r['cover_s'][1]} | {100 * r['err_w']:.1f}% / {100 * r['err_s']:.1f}% | {r['s_workbench']:.2f} / "
              f"{r['s_sysid']:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
