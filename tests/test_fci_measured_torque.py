"""The measured joint torque tau_J of the simulated robot is the torque its joints applied, in every control mode.

The plant's joint velocity servos (FrankaSim's velocity and position control, and the FCI server's internal joint
impedance controller) are integrated implicitly by MuJoCo, so their force over a step acts at the end-of-step
velocity; tau_J must include that share. Checked three ways: in-process against the model's inverse dynamics for
every FCI mode and FrankaSim's velocity control; with libfranka's own model (built by pylibfranka from the URDF the
server sends) on a log recorded under the internal joint impedance controller; and with the workbench's ``compare``
on logs of pylibfranka joint-position control and franky joint motions (no residual proportional to ddq)."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
from conftest import record_with_client

from franka_vs_gym.fci.codec import MoveControllerMode as C
from franka_vs_gym.fci.codec import MoveMotionGeneratorMode as G
from franka_vs_gym.fci.codec import RobotCommand
from franka_vs_gym.fci.robot import FCIRobot
from franka_vs_gym.model import FrankaModel, ModelConfig
from franka_vs_gym.sim import JOINT_STATE, STOP, VELOCITY, FrankaSim

DT = 0.001
# below the smallest noise floor of a real FER's torque sensors (Gaz et al. 2019 log: 0.027 Nm on joint 6)
FLOOR = 0.02
# the share the implicit servo damping adds to tau_J, dt * D * ddq, shows up as an armature of 0.007-0.14 kg m^2
# per joint when it is missing; a model-plant match leaves a few 1e-3 at most
ARMATURE_TOL = 0.005

AMP = np.array([0.2, 0.15, 0.2, 0.2, 0.25, 0.25, 0.3])
W = 2 * math.pi * np.array([0.31, 0.43, 0.37, 0.53, 0.61, 0.47, 0.71])  # rad/s
KP = np.array([600.0, 600, 600, 600, 250, 150, 50])  # Nm/rad
KD = np.array([50.0, 50, 50, 50, 20, 15, 5])  # Nm s/rad


def _window(s: float, T: float) -> tuple[float, float]:
    """sin^2 window over [0, T] and its derivative: motions that start and end at rest without a jerk step."""
    return math.sin(math.pi * s / T) ** 2, math.pi / T * math.sin(2 * math.pi * s / T)


def _command(k: int, q_c=None, dq_c=None, T_c=None, v_c=None, tau=None) -> RobotCommand:
    z = np.zeros(7)
    return RobotCommand(k, z if q_c is None else q_c, z if dq_c is None else dq_c,
                        np.eye(4).ravel(order="F") if T_c is None else T_c.ravel(order="F"),
                        np.zeros(6) if v_c is None else v_c, np.zeros(2), False, False, z if tau is None else tau,
                        False)


MODES = {"torque": (C.EXTERNAL_CONTROLLER, G.NONE), "joint_position": (C.JOINT_IMPEDANCE, G.JOINT_POSITION),
         "joint_velocity": (C.JOINT_IMPEDANCE, G.JOINT_VELOCITY),
         "cartesian_pose": (C.JOINT_IMPEDANCE, G.CARTESIAN_POSITION),
         "cartesian_velocity": (C.JOINT_IMPEDANCE, G.CARTESIAN_VELOCITY),
         "cartesian_impedance": (C.CARTESIAN_IMPEDANCE, G.CARTESIAN_POSITION), "idle_hold": None}
SERVO_MODES = {"joint_position", "joint_velocity", "cartesian_pose", "cartesian_velocity", "idle_hold"}


@pytest.mark.parametrize("rotor", [False, True])
@pytest.mark.parametrize("mode", list(MODES))
def test_fci_tau_J_is_the_applied_torque_in_every_mode(mode, rotor):
    """tau_J in the robot state = B(q) ddq + C dq + g + tau_f(dq) of the step just taken (float32 on the wire),
    whether the joints are driven by the client's torques, the internal joint impedance (its damping in the plant's
    implicit velocity servos) or the internal Cartesian impedance; with the motors' effective armature in the plant
    (as the FCI server's robot) too: the sensor stays link side."""
    sim = FrankaSim(camera=False, rotor_inertia=rotor)
    robot = FCIRobot(sim)
    model = FrankaModel()
    T, n = 1.0, 1000
    q0 = sim.q
    T0 = robot.O_T_EE_of(q0)
    if MODES[mode] is not None:
        robot.start_motion(*MODES[mode])
    d, dofs = sim.world.data, sim.dof_slice
    err, share = np.zeros(7), np.zeros(7)
    for k in range(1, n + 1):
        s = k * DT
        win, dwin = _window(s, T)
        q_c = q0 + AMP * win * np.sin(W * s)
        dq_c = AMP * (dwin * np.sin(W * s) + win * W * np.cos(W * s))
        p = 0.04 * np.array([math.sin(W[0] * s), math.sin(W[1] * s), math.sin(W[2] * s)])
        dp = 0.04 * W[:3] * np.cos(W[:3] * s)
        T_c = T0.copy()
        T_c[:3, 3] += win * p
        v_c = np.concatenate([dwin * p + win * dp, np.zeros(3)])
        tau_c = KP * (q_c - sim.q) + KD * (dq_c - sim.dq)  # external control: a joint PD (gravity-free, Nm)
        cmd = None if mode == "idle_hold" else _command(k, q_c=q_c, dq_c=dq_c, T_c=T_c, v_c=v_c, tau=tau_c)
        qa, va = sim.q, sim.dq
        if mode == "idle_hold" and k % 100 == 0:  # push the held arm around: the hold's servo must work
            sim.world.data.qvel[dofs] += 0.05
            qa, va = sim.q, sim.dq
        assert robot.step(cmd) == (), robot.reflex_detail
        tau_J = np.array(robot.fill_state().f["tau_J"], dtype=float)
        expected = model.inverse_dynamics(qa, va, (sim.dq - va) / DT)
        err = np.maximum(err, np.abs(tau_J - expected))
        # the actuators' torque minus what accelerated the motors (the effective armature) reaches the link
        link_side = d.qfrc_actuator[dofs] - sim.rotor_inertia * (sim.dq - va) / DT
        share = np.maximum(share, np.abs(tau_J - link_side))
    # float32 of torques up to ~50 Nm: 4e-6 Nm; the model (pinocchio) and the plant (MuJoCo) agree to ~1e-6
    assert err.max() < 1e-4, (mode, err)
    if mode in SERVO_MODES:  # the implicit servo share is material here: a reading without it would fail above
        assert share.max() > 0.02, (mode, share)
    else:
        assert share.max() < 1e-4, (mode, share)


def test_sim_velocity_control_torque_reading_includes_the_servo_share():
    """FrankaSim.get_force_torque in velocity control and at a stop (joint velocity servos), with and without a
    measurement delay, is the torque the joints applied over the step."""
    model = FrankaModel()
    for delay in (0.0, 0.003):
        cfg = ModelConfig(delay=delay, delay_channel="measurement")
        sim = FrankaSim(cfg, camera=False)
        sim.set_robot_state(VELOCITY)
        applied, seen, share = [], [], 0.0
        for k in range(1, 801):
            s = k * DT
            win, dwin = _window(s, 0.6)
            dq = 2 * AMP * (dwin * np.sin(W * s) + win * W * np.cos(W * s)) if s < 0.6 else np.zeros(7)
            if k == 700:
                sim.set_robot_state(STOP)
            elif k < 700:
                sim.set_velocity(JOINT_STATE, dq)
            qa, va = sim.q, sim.dq
            sim.step()
            applied.append(model.inverse_dynamics(qa, va, (sim.dq - va) / DT))
            seen.append(sim.get_force_torque(JOINT_STATE))
            share = max(share, float(np.abs(seen[-1] - sim.world.data.qfrc_actuator[sim.dof_slice]).max()))
        lag = int(round(delay / DT))
        applied, seen = np.array(applied), np.array(seen)
        np.testing.assert_allclose(seen[lag:], applied[:len(applied) - lag], atol=1e-6, rtol=0)
        if not delay:
            assert share > 0.05  # the servos' implicit share is material (Kv up to 120 Nm s/rad)


def _plant(rotor: float, **kw) -> FrankaSim:
    """A FER plant with its effective armature (rotor_inertia) scaled by ``rotor``."""
    from franka_vs_gym.model.description import FER
    return FrankaSim(ModelConfig(robot=FER.with_rotor_inertia(rotor)), camera=False, rotor_inertia=True, **kw)


@pytest.mark.parametrize("rotor", [0.0, 1.0])
def test_torque_control_reading_is_qfrc_actuator_bit_for_bit(rotor):
    """In torque control (no servo gains) nothing is added: without an effective armature the reading is MuJoCo's
    actuator torque bit for bit, as before; with one, the actuator torque minus rotor_inertia * ddq of the step."""
    sim = _plant(rotor)
    from franka_vs_gym.sim import FORCE_TORQUE

    sim.set_robot_state(VELOCITY)
    sim.set_velocity(JOINT_STATE, np.full(7, 0.2))
    for _ in range(20):
        sim.step()
    sim.set_robot_state(FORCE_TORQUE)
    for k in range(50):
        sim.set_force_torque(JOINT_STATE, np.full(7, 0.5 * math.sin(0.1 * k)))
        dq0 = sim.dq
        sim.step()
        if rotor == 0.0:
            assert np.array_equal(sim.get_force_torque(), sim.world.data.qfrc_actuator[sim.dof_slice])
        else:
            motors = sim.rotor_inertia * (sim.dq - dq0) / DT
            np.testing.assert_allclose(sim.get_force_torque(),
                                       sim.world.data.qfrc_actuator[sim.dof_slice] - motors, atol=1e-9, rtol=0)


def test_saturated_servo_reading_is_the_clamped_torque():
    """A velocity servo driving its joint into the torque limit: MuJoCo integrates the clamped torque explicitly (no
    implicit share), and the reading is the limit, as the joint applied it (the motors' torque; the link side gets
    it minus what accelerates the motors, rotor_inertia * ddq)."""
    sim = FrankaSim(camera=False, reflexes=False)
    model = FrankaModel()
    sim.set_robot_state(VELOCITY)
    cmd = np.zeros(7)
    cmd[[0, 4]] = 2.0, 2.5  # rad/s from rest: Kv * 2 rad/s is beyond 87 / 12 Nm
    for _ in range(3):
        sim.set_velocity(JOINT_STATE, cmd)
        qa, va = sim.q, sim.dq
        sim.step()
        tau = sim.get_force_torque()
        motors = tau + sim.rotor_inertia * (sim.dq - va) / DT
        np.testing.assert_allclose(motors[[0, 4]], [87.0, 12.0], atol=1e-9)
        np.testing.assert_allclose(tau, model.inverse_dynamics(qa, va, (sim.dq - va) / DT), atol=1e-6)


# ---------------------------------------------------------------------------------------------- real clients




def _armature_and_lag(res) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares fit, per joint, of the compare residual r = a ddq - lag dtau_model/dt: the apparent armature
    a (kg m^2) and the lag (s) of the measured torque behind the motion. The lag is a property of any discrete
    plant's torque reading (the torque applied over the 1 ms step that ends at the reported state), the same in
    torque control; fitted alone, the armature would absorb part of it (about -0.006 kg m^2 on joint 1 of the
    pylibfranka motion, identically in torque control)."""
    r, ddq = res.residual, res.data.ddq
    tau_model = res.data.tau - r
    dtau = np.gradient(tau_model, res.data.time, axis=0)
    a, lag = np.zeros(7), np.zeros(7)
    for j in range(7):
        a[j], m = np.linalg.lstsq(np.column_stack([ddq[:, j], dtau[:, j]]), r[:, j], rcond=None)[0]
        lag[j] = -m
    return a, lag


def _check_compare(log) -> None:
    from franka_vs_gym.validation import compare

    res = compare(log)
    assert (res.rmse_tau <= np.hypot(res.noise_floor, FLOOR)).all(), (res.rmse_tau, res.noise_floor)
    a, lag = _armature_and_lag(res)
    assert (np.abs(a) < ARMATURE_TOL).all(), a
    assert ((lag > 0) & (lag < 1.5 * DT)).all(), lag


@pytest.mark.skipif(importlib.util.find_spec("pylibfranka") is None, reason="pylibfranka is not installed")
def test_pylibfranka_joint_position_control_log_matches_libfranka_model_and_compare(tmp_path):
    from franka_vs_gym.validation import load_log

    out = record_with_client("record_joint_position.py", tmp_path, 41)
    assert out["n"] == 4002 and out["dropped"] == 0
    z = np.load(tmp_path / "libfranka_model.npz")
    np.testing.assert_allclose(np.diff(z["time"]), DT, atol=1e-9)  # one state per 1 ms physics step
    # independent: libfranka's model of each state (pinocchio on the URDF the server sends) + the friction law
    dq, ddq = z["dq"], np.diff(z["dq"], axis=0) / DT
    friction = FrankaModel().friction
    expected = (np.einsum("kij,kj->ki", z["mass"][:-1], ddq) + z["coriolis"][:-1] + z["gravity"][:-1]
                + np.array([friction(v) for v in dq[:-1]]))
    err = np.abs(z["tau_J"][1:] - expected).max(axis=0)
    assert (err < 1e-3).all(), err  # without the servo share: 0.05-0.23 Nm
    _check_compare(load_log(tmp_path / "recorded.csv"))


@pytest.mark.skipif(importlib.util.find_spec("franky") is None, reason="franky is not installed")
def test_franky_joint_motion_log_has_no_ddq_proportional_residual(tmp_path):
    from franka_vs_gym.validation import load_log

    out = record_with_client("record_franky_joint_motion.py", tmp_path, 42)
    assert out["n"] > 2000 and out["dropped"] == 0
    _check_compare(load_log(tmp_path / "recorded.npz"))
