"""The simulated FER's reflexes: one test per limit with libfranka's reason string, brakes, recovery, hard stops."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import run_in_both_plants

from franka_vs_gym.model.config import ModelConfig
from franka_vs_gym.model.description import FER
from franka_vs_gym.sim import FORCE_TORQUE, JOINT_STATE, POSITION, VELOCITY, FrankaSim, plant
from franka_vs_gym.sim.reflexes import ControlException, position_profile_time

LIM = FER.limits
Q0 = np.array(FER.q_neutral)

# libfranka's printed error names (research interface getErrorName), verified against libfranka's public sources
LIBFRANKA_NAMES = {"joint_position_limits_violation", "joint_velocity_violation", "tau_J_range_violation",
                   "controller_torque_discontinuity", "joint_motion_generator_velocity_discontinuity",
                   "joint_motion_generator_acceleration_discontinuity"}


def _torque_until_reflex(sim: FrankaSim, tau: np.ndarray, seconds: float = 2.0) -> ControlException:
    sim.set_robot_state(FORCE_TORQUE)
    with pytest.raises(ControlException) as e:
        for _ in range(int(seconds / sim.dt)):
            sim.set_force_torque(JOINT_STATE, tau)
            sim.step()
    return e.value


def test_joint_velocity_limit_stops_the_robot_and_holds_it():
    """The issue's case: 87 Nm gravity-free on joint index 2 for 2 s."""
    sim = FrankaSim(camera=False)
    tau = np.zeros(7)
    tau[2] = 87.0
    e = _torque_until_reflex(sim, tau)
    assert e.reasons == ("joint_velocity_violation",) and "joint 2" in e.detail
    assert sim.current_errors == ("joint_velocity_violation",)
    assert np.abs(sim.get_velocity()[2]) <= LIM.dq_max[2] * 1.2  # caught within a step of the limit
    q = sim.get_position()
    assert q[2] < LIM.q_max[2]
    # brakes: held whatever is commanded, commands refused until recovery
    with pytest.raises(ControlException, match="automatic_error_recovery"):
        sim.set_force_torque(JOINT_STATE, tau)
    sim.wait(0.3)
    np.testing.assert_allclose(sim.get_position(), q, atol=1e-12)
    sim.automatic_error_recovery()
    assert sim.current_errors == ()
    sim.wait(0.3)
    assert np.abs(sim.get_position() - q).max() < 1e-3  # stopped, not falling


@pytest.mark.parametrize("joint,sign", [(0, 1), (3, 1), (5, -1), (6, 1)])
def test_joint_position_limit(joint, sign):
    """Start next to a limit, push into it slowly: joint_position_limits_violation at the limit."""
    q0 = Q0.copy()
    lim = LIM.q_max[joint] if sign > 0 else LIM.q_min[joint]
    q0[joint] = lim - sign * 0.01
    sim = FrankaSim(camera=False, q0=q0)
    sim.set_robot_state(VELOCITY)
    v = np.zeros(7)
    v[joint] = sign * 0.2
    with pytest.raises(ControlException) as e:
        for _ in range(500):
            sim.set_velocity(JOINT_STATE, v)
            sim.step()
    assert e.value.reasons == ("joint_position_limits_violation",) and f"joint {joint}" in e.value.detail
    q = sim.get_position()[joint]
    assert abs(q - lim) < 2e-3  # stopped at the limit
    # after recovery, moving back inside is allowed, moving further out is not
    sim.automatic_error_recovery()
    sim.set_robot_state(VELOCITY)
    for _ in range(200):
        sim.set_velocity(JOINT_STATE, -v)
        sim.step()
    assert sign * (lim - sim.get_position()[joint]) > 0.02
    for _ in range(100):  # turn around: out again -> reflex again
        sim.set_velocity(JOINT_STATE, v)
        sim.step()
    with pytest.raises(ControlException, match="joint_position_limits_violation"):
        for _ in range(500):
            sim.set_velocity(JOINT_STATE, v)
            sim.step()


def test_recovery_beyond_the_limit_allows_only_moving_back():
    q0 = Q0.copy()
    q0[0] = LIM.q_max[0] - 1e-3
    sim = FrankaSim(camera=False, q0=q0)
    sim._qpos[0] = LIM.q_max[0] + 0.01  # as if it overshot
    with pytest.raises(ControlException, match="joint_position_limits_violation"):
        sim.step()
    sim.automatic_error_recovery()
    sim.set_robot_state(VELOCITY)
    for _ in range(300):
        sim.set_velocity(JOINT_STATE, [-0.1, 0, 0, 0, 0, 0, 0])
        sim.step()
    assert sim.get_position()[0] < LIM.q_max[0]
    assert sim.current_errors == ()


def test_tau_J_range_violation():
    """A torque-sensor offset makes the measured torque exceed the wrist's 12 Nm at full command."""
    cfg = ModelConfig(torque_offset=[0, 0, 0, 0, 0, 0, 3.0])
    sim = FrankaSim(cfg, camera=False)
    tau = np.zeros(7)
    tau[6] = 11.0
    e = _torque_until_reflex(sim, tau, 0.05)
    assert e.reasons == ("tau_J_range_violation",) and "joint 6" in e.detail


def test_controller_torque_discontinuity_in_check_mode():
    sim = FrankaSim(camera=False, command_rates="check")
    sim.set_robot_state(FORCE_TORQUE)
    ok = np.zeros(7)
    ok[0] = 0.9  # 0.9 Nm within a 1 ms cycle: 900 Nm/s < 1000 Nm/s
    sim.set_force_torque(JOINT_STATE, ok)
    sim.step()
    jump = ok.copy()
    jump[0] = 2.0  # +1.1 Nm in one cycle: 1100 Nm/s
    with pytest.raises(ControlException) as e:
        sim.set_force_torque(JOINT_STATE, jump)
    assert e.value.reasons == ("controller_torque_discontinuity",) and "joint 0" in e.value.detail
    assert sim.current_errors == ("controller_torque_discontinuity",)


def test_torque_rate_limited_in_limit_mode():
    sim = FrankaSim(camera=False, command_rates="limit")
    sim.set_robot_state(FORCE_TORQUE)
    tau = np.zeros(7)
    tau[0] = 10.0
    applied = []
    for _ in range(15):
        sim.set_force_torque(JOINT_STATE, tau)
        sim.step()
        applied.append(sim._ctrl_tau[0])
    steps = np.diff([0.0] + applied)
    assert steps.max() <= LIM.dtau_max[0] * sim.dt + 1e-12
    assert applied[-1] == pytest.approx(10.0)
    assert sim.current_errors == ()


def test_velocity_and_acceleration_discontinuity_in_check_mode():
    sim = FrankaSim(camera=False, command_rates="check")
    sim.set_robot_state(VELOCITY)
    # a smooth ramp passes
    for k in range(20):
        sim.set_velocity(JOINT_STATE, [0.002 * k * k / 20, 0, 0, 0, 0, 0, 0])
        sim.step()
    # a jump of 0.1 rad/s within one cycle: 100 rad/s^2 > 15 and a jerk of 1e5 rad/s^3
    with pytest.raises(ControlException) as e:
        sim.set_velocity(JOINT_STATE, [0.1, 0, 0, 0, 0, 0, 0])
    assert set(e.value.reasons) == {"joint_motion_generator_velocity_discontinuity",
                                    "joint_motion_generator_acceleration_discontinuity"}
    # jerk alone: an acceleration step from 0 to 10 rad/s^2 (within ddq_max = 15) is 1e4 rad/s^3 > 7500
    sim = FrankaSim(camera=False, command_rates="check")
    sim.set_robot_state(VELOCITY)
    with pytest.raises(ControlException) as e:
        sim.set_velocity(JOINT_STATE, [0.01, 0, 0, 0, 0, 0, 0])
    assert e.value.reasons == ("joint_motion_generator_acceleration_discontinuity",)


def test_velocity_commands_rate_limited_in_limit_mode():
    sim = FrankaSim(camera=False, command_rates="limit")
    sim.set_robot_state(VELOCITY)
    target = np.array([0.5, -0.4, 0.3, 0.5, -0.8, 0.8, 1.0])
    refs = []
    for _ in range(400):
        sim.set_velocity(JOINT_STATE, target)
        sim.step()
        refs.append(sim._ctrl_vel.copy())
    refs = np.array([np.zeros(7)] + refs)
    acc = np.diff(refs, axis=0) / sim.dt
    jerk = np.diff(acc, axis=0) / sim.dt
    assert (np.abs(acc) <= np.array(LIM.ddq_max) + 1e-9).all()
    assert (np.abs(jerk[:-1]) <= np.array(LIM.dddq_max) * (1 + 1e-9)).all()
    assert (np.abs(refs) <= np.abs(target) + np.array(LIM.dddq_max) * sim.dt**2 + 1e-12).all()  # discrete stop
    np.testing.assert_allclose(refs[-1], target)
    np.testing.assert_allclose(sim.get_velocity(), target, atol=2e-2)  # the joint servo follows


def test_reflexes_can_be_switched_off_and_hard_stops_hold():
    sim = FrankaSim(camera=False, reflexes=False)
    assert sim.reflexes is False
    tau = np.zeros(7)
    tau[2] = 87.0
    sim.set_robot_state(FORCE_TORQUE)
    peak = 0.0
    for _ in range(2000):
        sim.set_force_torque(JOINT_STATE, tau)
        sim.step()
        peak = max(peak, sim.get_position()[2])
    # the hard stop holds: 0.03 rad of overshoot at the impact, resting within 1e-3 rad of the limit
    assert peak < LIM.q_max[2] + 0.04
    assert abs(sim.get_position()[2] - LIM.q_max[2]) < 1e-3
    assert sim.current_errors == ()


def test_set_position_respects_the_limits_and_bad_arguments():
    sim = FrankaSim(camera=False)
    sim.set_robot_state(POSITION)
    target = Q0 + 0.3
    sim.set_position(JOINT_STATE, target)
    np.testing.assert_allclose(sim.get_position(), target, atol=2e-4)
    assert sim.current_errors == ()
    with pytest.raises(ValueError, match="timeout"):
        sim.set_position(JOINT_STATE, Q0, timeout=0)
    with pytest.raises(ValueError, match="timeout"):
        sim.set_position(JOINT_STATE, Q0, timeout=float("nan"))
    sim.set_positioning_velocity(1e-9)
    with pytest.raises(ValueError, match="more than timeout"):
        sim.set_position(JOINT_STATE, Q0)
    d = np.array([1.0, 0, 0, 0, 0, 0, 0])
    T = position_profile_time(d, np.ones(7), np.ones(7), np.ones(7))
    assert T == pytest.approx(max(15 / 8, np.sqrt(10 / np.sqrt(3)), np.cbrt(60)))


def test_environment_ends_the_episode_with_the_reason():
    import gymnasium as gym

    import franka_vs_gym.envs  # noqa: F401

    env = gym.make("FrankaTorqueTracking-v0", action_scale="physical")
    env.reset(seed=0)
    a = np.zeros(7, np.float32)
    a[6] = 12.0  # full wrist torque: the light joint passes its velocity limit
    info = {}
    for _ in range(100):
        _, _, term, trunc, info = env.step(a)
        if term or trunc:
            break
    assert term and info["failure"] == "joint_velocity_violation", info
    assert "joint 6" in info["reflex"]
    env.reset(seed=1)
    assert env.unwrapped.sim.current_errors == ()
    env.close()


def test_reason_names_are_libfrankas():
    from franka_vs_gym.sim import reflexes as R

    names = {R.JOINT_POSITION, R.JOINT_VELOCITY, R.TAU_J_RANGE, R.TORQUE_DISCONTINUITY, R.VELOCITY_DISCONTINUITY,
             R.ACCELERATION_DISCONTINUITY}
    assert names == LIBFRANKA_NAMES
    try:
        from franka_vs_gym.fci.errors import ERROR_BITS
    except ImportError:  # pragma: no cover - the FCI server is optional
        return
    assert all(n in ERROR_BITS for n in names)  # the server's independent table of libfranka's bits knows them all


# ---------------------------------------------------------------- reflexes inside a multi-step call (compiled plant)
PERIOD = 50  # physics steps per call, as an environment's 50 ms control period


def _tau_j_offset() -> np.ndarray:
    """A torque-sensor offset on joint 1 that makes its measured torque cross 87 Nm after the 75th step of a 10 Nm
    command (the gravity torque changes as the arm moves), from a run without reflexes (the offset is measurement
    only: the motion is the same)."""
    s = FrankaSim(camera=False, reflexes=False)
    s.set_robot_state(FORCE_TORQUE)
    s.set_force_torque(JOINT_STATE, [0, 10, 0, 0, 0, 0, 0])
    tau = []
    for _ in range(100):
        s.step()
        tau.append(s._qfrc_actuator[1])
    assert (np.diff(tau) < 0).all()  # decreasing: one crossing
    o = np.zeros(7)
    o[1] = -LIM.tau_max[1] - (tau[73] + tau[74]) / 2
    return o


def _reflex_setup(limit: str):
    """A robot commanded once, then stepped: (sim, the ControlException's reason)."""
    if limit == "velocity":  # the case: 87 Nm on joint index 2
        sim = FrankaSim(camera=False)
        sim.set_robot_state(FORCE_TORQUE)
        sim.set_force_torque(JOINT_STATE, [0, 0, 87.0, 0, 0, 0, 0])
        return sim, "joint_velocity_violation"
    if limit == "position":  # joint 3 pushed into its upper limit
        q0 = Q0.copy()
        q0[3] = LIM.q_max[3] - 0.01
        sim = FrankaSim(camera=False, q0=q0)
        sim.set_robot_state(VELOCITY)
        sim.set_velocity(JOINT_STATE, [0, 0, 0, 0.3, 0, 0, 0])
        return sim, "joint_position_limits_violation"
    sim = FrankaSim(ModelConfig(torque_offset=_tau_j_offset()), camera=False)
    sim.set_robot_state(FORCE_TORQUE)
    sim.set_force_torque(JOINT_STATE, [0, 10, 0, 0, 0, 0, 0])
    return sim, "tau_J_range_violation"


def _run_until_reflex(sim: FrankaSim, n: int) -> ControlException:
    with pytest.raises(ControlException) as e:
        for _ in range(2000 // n):
            sim.world.step(n)
    return e.value


@pytest.mark.parametrize("limit", ["position", "velocity", "tau_J"])
def test_reflex_fires_at_the_crossing_step_inside_a_multi_step_call(limit):
    """world.step(50) (an environment's period, one call into MuJoCo) reports the violation at the physics step that
    crossed the limit, exactly as a reference stepping one physics step at a time (checked in Python after each
    step), with libfranka's reason, and holds the joints from that step on (then Python's brakes, until
    automatic_error_recovery)."""
    ref, reason = _reflex_setup(limit)
    ref.reflexes = False  # reference: the compiled checks off, the Python check after every physics step
    with pytest.raises(ControlException) as e_ref:
        for _ in range(2000):
            ref.world.step()
            ref._reflexes.check_state()
    e_ref = e_ref.value
    assert e_ref.reasons == (reason,)
    assert ref.world.data.userdata[3] == 0.0  # nothing recorded by the plant
    t_ref = ref.time

    sim, _ = _reflex_setup(limit)
    e = _run_until_reflex(sim, PERIOD)
    assert e.reasons == (reason,) and reason in LIBFRANKA_NAMES
    assert e.detail == e_ref.detail and e.detail.startswith(f"t={t_ref:.4f} s: joint ")  # time, joint, value
    k = round(t_ref / sim.dt)
    assert k % PERIOD != 0  # in the middle of a call
    if plant.NATIVE:  # recorded by the plant at the crossing step, the call ran to its end
        assert sim.world.data.userdata[3] == t_ref
        assert round(sim.time / sim.dt) == (k // PERIOD + 1) * PERIOD
    else:  # the pure-Python fallback checks before every step and stops the call there
        assert sim.time == t_ref
    np.testing.assert_array_equal(sim.q, ref.q)  # held where the reference stopped, bit for bit
    assert sim.current_errors == (reason,)
    for _ in range(3):  # brakes: held (to the hard stop's push within one step), and still in error
        sim.world.step(PERIOD)
        np.testing.assert_allclose(sim.q, ref.q, rtol=0, atol=1e-4)
    sim.set_robot_state(FORCE_TORQUE)
    with pytest.raises(ControlException, match="automatic_error_recovery"):
        sim.set_force_torque(JOINT_STATE, np.zeros(7))
    sim.automatic_error_recovery()  # releases the brakes
    assert sim.current_errors == ()
    if limit == "velocity":
        sim.set_robot_state(FORCE_TORQUE)
        sim.set_force_torque(JOINT_STATE, [0, 0, 0, 0, 0, 0, 0.2])
        sim.world.step(PERIOD)
        assert abs(sim.q[6] - ref.q[6]) > 1e-3  # moves again
    elif limit == "position":  # back inside is allowed, further out is not (checked in Python at every step)
        sim.set_robot_state(VELOCITY)
        sim.set_velocity(JOINT_STATE, [0, 0, 0, -0.2, 0, 0, 0])
        sim.world.step(PERIOD)
        assert sim.q[3] < ref.q[3] - 1e-3
        sim.set_velocity(JOINT_STATE, [0, 0, 0, 0.2, 0, 0, 0])
        with pytest.raises(ControlException, match="joint_position_limits_violation"):
            for _ in range(20):
                sim.world.step(PERIOD)


def test_the_plant_holds_the_joints_from_the_crossing_step():
    """Inside one mujoco.mj_step(m, d, n) call (no Python in between), the compiled plant records the violation and
    brakes: the joints stay at the recorded position while the free robot runs on."""
    import mujoco

    if not plant.NATIVE:
        pytest.skip(plant.unavailable_reason())
    free, _ = _reflex_setup("velocity")
    free.reflexes = False
    sim, _ = _reflex_setup("velocity")
    for s in (free, sim):
        mujoco.mj_step(s.world.model, s.world.data, PERIOD)
    rec = sim.world.data.userdata
    assert rec[0] == 2 and rec[4] == 2 and rec[5] > LIM.dq_max[2]  # velocity violation of joint 2, its value
    assert np.abs(sim.q - rec[6:13]).max() < 1e-12 and np.abs(sim.dq).max() < 1e-12
    assert abs(free.q[2] - rec[8]) > 0.05  # without the brakes the joint ran on
    assert not sim.world.data.ctrl[sim._motor].any() and not sim.world.data.ctrl[sim._vel].any()


def test_pure_python_fallback_reports_the_same_reflex():
    """Without the compiled plant (FRANKA_VS_GYM_PURE_PYTHON=1) the checks run in Python at every physics step:
    the same reason, time and joint (the value agrees to the fallback's friction rounding)."""
    if not plant.NATIVE:
        pytest.skip(plant.unavailable_reason())

    code = ("import numpy as np; from franka_vs_gym.sim import FrankaSim, FORCE_TORQUE, JOINT_STATE, plant\n"
            "from franka_vs_gym.sim.reflexes import ControlException\n"
            "s = FrankaSim(camera=False); s.set_robot_state(FORCE_TORQUE)\n"
            "s.set_force_torque(JOINT_STATE, [0, 0, 87.0, 0, 0, 0, 0])\n"
            "try:\n    [s.world.step(50) for _ in range(10)]\n"
            "except ControlException as e:\n    print(plant.NATIVE, e.reasons[0], e.detail)")
    out = {flag: stdout.split() for flag, stdout in run_in_both_plants(code).items()}
    assert out["1"][0] == "False" and out["0"][1] == out["1"][1] == "joint_velocity_violation"
    assert out["0"][2:6] == out["1"][2:6]  # "t=0.0140 s: joint 2"
    assert float(out["0"][7]) == pytest.approx(float(out["1"][7]), abs=1e-3)
