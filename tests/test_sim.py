"""FrankaSim: the vpRobotFranka-style API on the MuJoCo plant."""

import numpy as np
import pytest

from franka_vs_gym.assets.mjcf import RobotSpec, SceneSpec
from franka_vs_gym.model import FrankaModel, ModelConfig, RigidBody, params
from franka_vs_gym.sim import (
    CAMERA_FRAME,
    END_EFFECTOR_FRAME,
    FORCE_TORQUE,
    JOINT_STATE,
    POSITION,
    REFERENCE_FRAME,
    VELOCITY,
    FrankaSim,
    SimulationDiverged,
    SimWorld,
)

Q0 = params.as_array(params.Q_NEUTRAL)


@pytest.fixture
def sim():
    return FrankaSim(camera=False)


def test_zero_torque_holds_still_gravity_added_by_robot(sim):
    sim.set_robot_state(FORCE_TORQUE)
    for _ in range(500):
        sim.set_force_torque(JOINT_STATE, np.zeros(7))
        sim.step()
    np.testing.assert_allclose(sim.get_position(), Q0, atol=1e-9)
    # the measured link-side torque is g(q), as libfranka's tau_J at rest
    np.testing.assert_allclose(sim.get_force_torque(), sim.get_gravity(), atol=1e-9)
    assert sim.time == pytest.approx(0.5)


@pytest.mark.parametrize("rotor", [0.0, 1.0])
def test_measured_torque_follows_the_model_equation(rng, rotor):
    """tau_J = B ddq + C dq + g + tau_f(dq) along a torque-driven motion with friction on (plant vs model).
    The motion takes joint 4 past its velocity limit: the plant's physics, with the reflexes off. Without an
    effective armature the sensor reads the command plus gravity; with one (the FER's default), the command plus
    gravity minus what accelerates the motors, rotor_inertia * ddq, and the link-side equation still holds."""
    from franka_vs_gym.model.config import ModelConfig
    from franka_vs_gym.model.description import FER
    sim = FrankaSim(ModelConfig(robot=FER.with_rotor_inertia(rotor)), camera=False, reflexes=False,
                    rotor_inertia=True)
    sim.set_robot_state(FORCE_TORQUE)
    m = sim.model
    rot = np.array(FER.rotor_inertia) * rotor
    for k in range(300):
        tau = 3.0 * np.sin(0.01 * k + np.arange(7)) * np.array([5, 5, 5, 5, 0.5, 0.3, 0.05])
        q, dq = sim.get_position(), sim.get_velocity()
        sim.set_force_torque(JOINT_STATE, tau)
        sim.step()
        ddq = sim.get_acceleration()
        np.testing.assert_allclose((sim.get_velocity() - dq) / sim.dt, ddq, atol=1e-6)
        np.testing.assert_allclose(sim.get_force_torque(), tau + m.gravity(q) - rot * ddq, atol=1e-9)
        np.testing.assert_allclose(m.inverse_dynamics(q, dq, ddq), sim.get_force_torque(), atol=1e-6)
    assert np.abs(sim.get_velocity()).max() > 0.05


def test_friction_switch(rng):
    # without friction the wrist passes its velocity limit: plant physics, reflexes off
    a, b = FrankaSim(camera=False, reflexes=False), FrankaSim(camera=False, friction=False, reflexes=False)
    for s in (a, b):
        s.set_robot_state(FORCE_TORQUE)
        for _ in range(200):
            s.set_force_torque(JOINT_STATE, [0, 0, 0, 0, 0, 0, 0.5])
            s.step()
    # with friction the wrist accelerates less
    assert abs(a.get_velocity()[6]) < abs(b.get_velocity()[6]) - 0.05


def test_joint_velocity_command_tracks_and_is_limited(sim):
    sim.set_robot_state(VELOCITY)
    cmd = np.array([0.2, -0.1, 0.1, 0.15, -0.2, 0.2, -0.3])
    for _ in range(300):
        sim.set_velocity(JOINT_STATE, cmd)
        sim.step()
    np.testing.assert_allclose(sim.get_velocity(), cmd, atol=2e-3)
    # beyond the limits: scaled down uniformly, direction kept
    big = np.array([10.0, 0, 0, 0, 0, 0, 5.0])
    for _ in range(300):
        sim.set_velocity(JOINT_STATE, big)
        sim.step()
    v = sim.get_velocity()
    assert abs(v[0]) <= params.DQ_MAX[0] + 1e-2
    assert v[6] / v[0] == pytest.approx(0.5, abs=0.02)


@pytest.mark.parametrize("frame", [END_EFFECTOR_FRAME, CAMERA_FRAME, REFERENCE_FRAME])
def test_cartesian_velocity_commands(frame):
    sim = FrankaSim(camera=True)
    sim.set_robot_state(VELOCITY)
    twist = np.array([0.03, -0.02, 0.04, 0.1, -0.05, 0.2])
    for _ in range(200):
        sim.set_velocity(frame, twist)
        sim.step()
    np.testing.assert_allclose(sim.get_velocity(frame), twist, atol=2e-3)


def test_camera_twist_moves_camera_frame():
    """A pure translation along the camera z axis moves the camera origin along its optical axis."""
    sim = FrankaSim(camera=True)
    M0 = sim.get_fMc()
    sim.set_robot_state(VELOCITY)
    for _ in range(500):
        sim.set_velocity(CAMERA_FRAME, [0, 0, 0.05, 0, 0, 0])
        sim.step()
    M1 = sim.get_fMc()
    d = M1[:3, 3] - M0[:3, 3]
    assert np.linalg.norm(d) == pytest.approx(0.025, rel=0.05)
    assert d @ M0[:3, 2] / np.linalg.norm(d) > 0.999


def test_set_position_moves_there(sim):
    sim.set_robot_state(POSITION)
    target = np.array([0.3, -0.5, 0.1, -2.0, 0.1, 1.6, 0.5])
    sim.set_position(JOINT_STATE, target)
    np.testing.assert_allclose(sim.get_position(), target, atol=2e-4)
    pose = sim.model.fMe(np.array([-0.2, -0.6, 0.0, -2.2, 0.0, 1.7, 0.6]))
    sim.set_position(END_EFFECTOR_FRAME, pose)
    np.testing.assert_allclose(sim.get_fMe(), pose, atol=1e-3)


def test_torque_saturation(sim):
    """Commands saturate at the FER limits; the total (command + gravity) is clamped too."""
    sim.set_robot_state(FORCE_TORQUE)
    g = sim.get_gravity()
    sim.set_force_torque(JOINT_STATE, [500, 0, 0, 0, -100, 0, 0])
    sim.step()
    tau = sim.get_force_torque()
    assert tau[0] == pytest.approx(min(87.0, 87.0 + g[0]))
    assert tau[4] == pytest.approx(max(-12.0, -12.0 + g[4]))


@pytest.mark.parametrize("cmd, match", [
    ([0.0] * 6, "shape"), ([0, 0, 0, float("nan"), 0, 0, 0], "NaN"), ([0, 0, 0, 0, 0, 0, float("inf")], "NaN or inf"),
    ("abc", "numeric"),
])
def test_bad_commands_raise_before_reaching_mujoco(sim, cmd, match):
    sim.set_robot_state(FORCE_TORQUE)
    with pytest.raises(ValueError, match=match):
        sim.set_force_torque(JOINT_STATE, cmd)
    assert np.all(sim._d.ctrl == 0)
    sim.set_robot_state(VELOCITY)
    with pytest.raises(ValueError):
        sim.set_velocity(JOINT_STATE, cmd)


def test_wrong_state_is_an_error(sim):
    with pytest.raises(RuntimeError, match="STATE_VELOCITY_CONTROL"):
        sim.set_velocity(JOINT_STATE, np.zeros(7))
    with pytest.raises(RuntimeError, match="STATE_FORCE_TORQUE_CONTROL"):
        sim.set_force_torque(JOINT_STATE, np.zeros(7))


def test_divergence_is_detected_not_returned_as_nan(sim):
    sim.set_robot_state(FORCE_TORQUE)
    sim._d.qvel[:] = np.nan
    with pytest.raises(SimulationDiverged, match="diverged"):
        sim.step()


def test_reset_rejects_out_of_limits(sim):
    with pytest.raises(ValueError, match="joint limits"):
        sim.reset(np.full(7, 3.5))


def test_two_robots_tilted_mountings_step_synchronously():
    """Two FERs mounted on the sides of a common base: each one's gravity compensation uses gravity in its own
    base frame, and one world step moves both."""
    c = np.cos(np.pi / 4)
    world = SimWorld(SceneSpec(robots=[
        RobotSpec("left_", (0, 0.2, 0.6), (c, c, 0, 0), camera=False),
        RobotSpec("right_", (0, -0.2, 0.6), (c, -c, 0, 0), ft_sensor=True)]))
    left, right = FrankaSim(world=world, prefix="left_"), FrankaSim(world=world, prefix="right_")
    np.testing.assert_allclose(left.model.config.gravity, [0, -9.81, 0], atol=1e-12)
    np.testing.assert_allclose(right.model.config.gravity, [0, 9.81, 0], atol=1e-12)
    left.set_robot_state(FORCE_TORQUE)
    right.set_robot_state(VELOCITY)
    for _ in range(200):
        left.set_force_torque(JOINT_STATE, np.zeros(7))
        right.set_velocity(JOINT_STATE, [0.1, 0, 0, 0, 0, 0, 0])
        world.step()
    np.testing.assert_allclose(left.get_position(), Q0, atol=1e-8)
    assert right.get_position()[0] == pytest.approx(0.02, abs=2e-3)
    assert left.time == right.time == pytest.approx(0.2)
    # the resting F/T sensor sees no external wrench
    np.testing.assert_allclose(right.get_ft_wrench(), 0.0, atol=1e-3)


def test_ft_sensor_measures_a_known_contact_force():
    """Push the tool with a known external force (xfrc_applied at the TCP): the F/T wrench reads it in e."""
    sim = FrankaSim(camera=False, ft_sensor=True)
    sim.set_robot_state(FORCE_TORQUE)
    F = np.array([5.0, -3.0, 8.0])
    b = sim._hand_body
    ee = sim._d.site_xpos[sim._ee_site].copy()
    for _ in range(3):
        sim._d.xfrc_applied[b, :3] = F
        sim._d.xfrc_applied[b, 3:] = np.cross(ee - sim._d.xipos[b], F)
        sim.set_force_torque(JOINT_STATE, np.zeros(7))
        sim.step()
    fMe = sim.get_fMe()
    w = sim.get_ft_wrench()
    np.testing.assert_allclose(w[:3], fMe[:3, :3].T @ F, atol=0.05)


def test_payload_unknown_to_the_robot_is_not_compensated():
    sim = FrankaSim(camera=False, undeclared_payload=RigidBody(1.0, [0, 0, 0.15], [1e-3, 1e-3, 1e-3]))
    sim.set_robot_state(FORCE_TORQUE)
    for _ in range(200):
        sim.set_force_torque(JOINT_STATE, np.zeros(7))
        sim.step()
    assert np.linalg.norm(sim.get_position() - Q0) > 1e-3  # it sags


def test_calibrated_model_file_builds_plant_and_model(tmp_path):
    cfg = ModelConfig(armature=np.full(7, 0.2), torque_offset=np.full(7, 0.3))
    path = cfg.save(tmp_path / "m.json")
    sim = FrankaSim(model=str(path), camera=False)
    assert sim._m.dof_armature[:7] == pytest.approx(np.full(7, 0.2))
    np.testing.assert_allclose(sim.get_force_torque(), sim.get_gravity() + 0.3, atol=1e-9)
    assert isinstance(sim.model, FrankaModel)


def test_delay_shifts_torque_by_whole_steps():
    sim = FrankaSim(ModelConfig(delay=0.005), camera=False, friction=False)
    sim.set_robot_state(FORCE_TORQUE)
    seen = []
    for k in range(10):
        sim.set_force_torque(JOINT_STATE, np.full(7, 1.0) if k == 0 else np.zeros(7))
        sim.step()
        seen.append(sim.get_force_torque()[6] - sim.get_gravity()[6])
    assert np.argmax(np.abs(seen)) == 5


def test_measurement_delay_makes_sensors_report_late():
    """delay_channel="measurement": the torque applies at once but the sensors report it 5 steps later."""
    sim = FrankaSim(ModelConfig(delay=0.005, delay_channel="measurement"), camera=False, friction=False)
    ref = FrankaSim(camera=False, friction=False)
    for s in (sim, ref):
        s.set_robot_state(FORCE_TORQUE)
    seen, truth = [], []
    for k in range(12):
        for s in (sim, ref):
            s.set_force_torque(JOINT_STATE, np.full(7, 1.0) if k == 0 else np.zeros(7))
            s.step()
        seen.append(sim.get_force_torque()[6])
        truth.append(ref.get_force_torque()[6])
        np.testing.assert_allclose(sim.get_position(), ref.get_position(), atol=1e-12)  # the motion is not delayed
    np.testing.assert_allclose(seen[5:], truth[:-5], atol=1e-9)


def test_vpRobotFranka_camelcase_aliases(sim):
    sim.setRobotState(VELOCITY)
    sim.setVelocity(JOINT_STATE, np.zeros(7))
    assert sim.getPosition(JOINT_STATE).shape == (7,)
    assert sim.getMass().shape == (7, 7)


def test_headless_rendering_even_when_mujoco_is_imported_first():
    """No display, MUJOCO_GL unset, mujoco imported before franka_vs_gym: the EGL context is swapped in."""
    import os
    import subprocess
    import sys

    code = ("import mujoco\nfrom franka_vs_gym.sim import FrankaSim\n"
            "img = FrankaSim(camera=False).world.render('overview', 64, 48)\nprint(img.shape, int(img.max()))")
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "DISPLAY", "PYOPENGL_PLATFORM")}
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "(48, 64, 3)" in r.stdout and not r.stdout.strip().endswith(" 0")


def test_friction_switch_at_run_time_matches_construction():
    """Toggling friction_enabled after construction gives the same motion as building the robot that way."""
    a, b = FrankaSim(camera=False, reflexes=False), FrankaSim(camera=False, friction=False, reflexes=False)
    a.friction_enabled = False
    for s in (a, b):
        s.set_robot_state(FORCE_TORQUE)
        for _ in range(100):
            s.set_force_torque(JOINT_STATE, [0, 0, 0, 0, 0, 0, 0.3])
            s.step()
    np.testing.assert_array_equal(a.get_position(), b.get_position())
    a.friction_enabled = True
    c = FrankaSim(camera=False, reflexes=False)
    for s in (a, c):
        s.reset(Q0)
        s.set_robot_state(FORCE_TORQUE)
        for _ in range(100):
            s.set_force_torque(JOINT_STATE, [0, 0, 0, 0, 0, 0, 0.3])
            s.step()
    np.testing.assert_array_equal(a.get_position(), c.get_position())
