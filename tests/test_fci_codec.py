"""The FCI server's parts without a client: codec round trips, error bits, the URDF, the FR3 velocity envelope."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from franka_vs_gym.fci import codec
from franka_vs_gym.fci.errors import ERROR_NAMES, error_bit, error_flags, error_names
from franka_vs_gym.fci.robot import FCIRobot
from franka_vs_gym.fci.urdf import robot_urdf, velocity_bounds, velocity_envelope
from franka_vs_gym.model import FrankaModel
from franka_vs_gym.model.config import ModelConfig, Tool
from franka_vs_gym.model.description import robot_description
from franka_vs_gym.sim import FrankaSim


def test_robot_state_round_trip():
    buf = codec.RobotStateBuffer()
    rng = np.random.default_rng(0)
    buf.floats[:] = rng.normal(size=codec.N_FLOATS).astype(np.float32)
    buf.errors[[0, 34]] = True
    buf.reflex_reason[32] = True
    buf.robot_mode = codec.RobotMode.REFLEX
    buf.motion_generator_mode = codec.MotionGeneratorMode.CARTESIAN_VELOCITY
    buf.control_command_success_rate = 0.75
    data = buf.encode(12345)
    assert len(data) == codec.ROBOT_STATE.size
    s = codec.decode_robot_state(data)
    assert s["message_id"] == 12345 and s["robot_mode"] == 4 and s["motion_generator_mode"] == 4
    assert np.array_equal(s["q"], buf.f["q"]) and np.array_equal(s["O_T_EE"], buf.f["O_T_EE"])
    assert error_names(s["errors"]) == ["joint_position_limits_violation", "tau_J_range_violation"]
    assert error_names(s["reflex_reason"]) == ["controller_torque_discontinuity"]
    assert s["control_command_success_rate"] == 0.75


def test_robot_command_round_trip():
    rng = np.random.default_rng(1)
    c = codec.RobotCommand(7, rng.normal(size=7), rng.normal(size=7), rng.normal(size=16), rng.normal(size=6),
                           rng.normal(size=2), True, False, rng.normal(size=7), True)
    data = c.encode()
    assert len(data) == codec.ROBOT_COMMAND.size == 8 + 38 * 8 + 2 + 7 * 8 + 1
    d = codec.RobotCommand.decode(data)
    assert d.message_id == 7 and d.valid_elbow and not d.motion_generation_finished and d.torque_command_finished
    for k in ("q_c", "dq_c", "O_T_EE_c", "O_dP_EE_c", "elbow_c", "tau_J_d"):
        assert np.array_equal(getattr(d, k), getattr(c, k))


def test_error_bits_as_the_client_decodes_them():
    assert len(ERROR_NAMES) == 41
    assert [error_bit(n) for n in ("joint_position_limits_violation", "joint_velocity_violation",
                                   "controller_torque_discontinuity", "tau_J_range_violation")] == [0, 3, 32, 34]
    assert error_bit("tau_j_range_violation") == 34  # the franka::Errors field spelling
    assert error_flags(["cartesian_reflex"]).nonzero()[0].tolist() == [7]
    with pytest.raises(ValueError, match="unknown libfranka error"):
        error_bit("no_such_error")


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_urdf_dynamics_and_kinematics_match_the_model(robot, rng):
    model = pin.buildModelFromXML(robot_urdf(robot))
    data = model.createData()
    assert model.nq == 7 and model.existFrame("link8")
    ref = FrankaModel(ModelConfig(robot=robot_description(robot), tool=Tool.none()))
    lim = robot_description(robot).limits
    for q in rng.uniform(np.array(lim.q_min), np.array(lim.q_max), size=(5, 7)):
        B = pin.crba(model, data, q)
        B = np.triu(B) + np.triu(B, 1).T
        assert np.abs(B - ref.mass_matrix(q)).max() < 1e-9
        assert np.abs(pin.computeGeneralizedGravity(model, data, q) - ref.gravity(q)).max() < 1e-9
        pin.framesForwardKinematics(model, data, q)
        assert np.abs(data.oMf[model.getFrameId("link8")].homogeneous - ref.fMfl(q)).max() < 1e-12


def test_fr3_position_based_velocity_limits():
    fr3 = robot_description("fr3")
    env = velocity_envelope(fr3)
    q = np.array(fr3.q_neutral, dtype=float)
    q[4] = fr3.limits.q_max[4] - 0.1  # joint 5 near its upper limit
    lo, up = velocity_bounds(q, fr3, env)
    assert up[4] == pytest.approx(-0.35 + np.sqrt(34.0 * 0.1))  # Franka's published curve for FR3 joint 5
    assert lo[4] == -5.26
    # a joint position command speeding joint 5 up towards its limit: within the constant limit (5.26 rad/s) but
    # faster than the FR3's position-based bound before it reaches the limit, so the FR3 rejects it
    robot = FCIRobot(FrankaSim(robot="fr3", camera=False, q0=q))
    robot.start_motion(codec.MoveControllerMode.JOINT_IMPEDANCE, codec.MoveMotionGeneratorMode.JOINT_POSITION)
    z = np.zeros(7)
    reasons, q_c = (), q.copy()
    for k in range(1, 600):
        q_c = q_c.copy()
        q_c[4] += 0.001 * 2.0 * (k / 600) ** 2  # speeding up towards 2 rad/s (acceleration < 10 rad/s^2)
        cmd = codec.RobotCommand(0, q_c, z, np.eye(4).ravel(), np.zeros(6), np.zeros(2), False, False, z, False)
        reasons = robot.step(cmd)
        if reasons:
            break
    assert reasons == ("joint_motion_generator_velocity_limits_violation",)
    assert robot.q_d[4] < fr3.limits.q_max[4] and "at " in robot.reflex_detail
