"""The rate limiter (franka_vs_gym.sim.rate_limit) against libfranka's documented behaviour: limited commands never
exceed the published limits, in-limit commands pass unchanged, and the vectorised functions give the same sequences
as a plain scalar transcription of the documented law, cycle by cycle."""

import math

import numpy as np
import pytest

from franka_vs_gym.sim.rate_limit import (
    CYCLE,
    FER_LIMITS,
    FR3_LIMITS,
    JointRateLimiter,
    fr3_joint_velocity_limits,
    limit_cartesian_pose,
    limit_cartesian_velocity,
    limit_joint_position,
    limit_joint_velocity,
    limit_torque_rate,
    rate_limits,
)


def _scalar_velocity(vmax_up, vmax_lo, A, J, cmd, v, a):
    """The documented scalar law, one joint, plain Python floats."""
    jerk = ((cmd - v) / CYCLE - a) / CYCLE
    jerk = max(min(jerk, J), -J)
    acc = a + jerk * CYCLE
    hi = min(J / A * (vmax_up - v), A)
    lo = max(J / A * (vmax_lo - v), -A)
    return v + max(min(acc, hi), lo) * CYCLE


def test_published_limits():
    # FER: 2.175 rad/s minus the 1e-3 margin and 3 lost packets at 15 rad/s^2
    assert FER_LIMITS.velocity_cap[0] == pytest.approx(2.175 - 1e-3 - 3e-3 * (15 - 1e-3))
    assert FER_LIMITS.joint_jerk[1] == pytest.approx(3750 - 1e-3)
    assert FR3_LIMITS.joint_acceleration[6] == pytest.approx(10 - 1e-3)
    assert rate_limits("fr3") is FR3_LIMITS and rate_limits("fer") is FER_LIMITS
    up, lo = FER_LIMITS.joint_velocity_limits(np.zeros(7))
    np.testing.assert_allclose(up, FER_LIMITS.velocity_cap)
    np.testing.assert_allclose(lo, -FER_LIMITS.velocity_cap)
    # FR3 in the middle of its range: the caps; at a position limit: zero towards it
    up, lo = fr3_joint_velocity_limits(np.array([0, 0, 0, -1.5, 0, 2.0, 0]))
    np.testing.assert_allclose(up, np.array([2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26]) - 1e-3)
    up, lo = fr3_joint_velocity_limits(FR3_LIMITS.q_upper)
    np.testing.assert_allclose(up, -1e-3)
    assert (lo < -1.0).all()
    # the published formula of joint 1: -0.30 + sqrt(12 (2.7501 - q))
    up, _ = fr3_joint_velocity_limits(np.array([2.7, 0, 0, -1.5, 0, 2.0, 0]))
    assert up[0] == pytest.approx(-0.30 + math.sqrt(12 * 0.0501) - 1e-3)


def test_torque_rate():
    last = np.zeros(7)
    ok = last + 0.5  # 500 Nm/s: within 1000 Nm/s
    np.testing.assert_array_equal(limit_torque_rate(ok, last, FER_LIMITS.torque_rate), ok)
    big = np.full(7, 10.0)
    out = limit_torque_rate(big, last, FER_LIMITS.torque_rate)
    np.testing.assert_allclose(out, FER_LIMITS.torque_rate * CYCLE)
    with pytest.raises(ValueError, match="NaN"):
        limit_torque_rate(np.full(7, np.nan), last, FER_LIMITS.torque_rate)


@pytest.mark.parametrize("limits", [FER_LIMITS, FR3_LIMITS], ids=["fer", "fr3"])
def test_joint_velocity_random_commands_respect_the_limits_and_match_the_scalar_law(limits):
    rng = np.random.default_rng(0)
    lim = JointRateLimiter(limits)
    q0 = np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.8, 0.0])
    lim.reset(q0)
    ref_v, ref_a = np.zeros(7), np.zeros(7)
    vs = [np.zeros(7)]
    for k in range(3000):
        if k % 40 == 0:
            target = rng.uniform(-4.0, 4.0, 7)  # beyond every velocity limit
        up, lo = limits.joint_velocity_limits(lim.q_d)
        v = lim.velocity(target)
        ref = np.array([_scalar_velocity(up[j], lo[j], limits.joint_acceleration[j], limits.joint_jerk[j],
                                         target[j], ref_v[j], ref_a[j]) for j in range(7)])
        np.testing.assert_array_equal(v, ref)
        ref_a = (ref - ref_v) / CYCLE
        ref_v = ref
        vs.append(v)
    vs = np.array(vs)
    acc = np.diff(vs, axis=0) / CYCLE
    jerk = np.diff(acc, axis=0) / CYCLE
    cap = limits.velocity_cap - limits.velocity_tolerance
    assert (np.abs(vs) <= cap + 1e-9).all()
    assert (np.abs(acc) <= limits.joint_acceleration * (1 + 1e-9)).all()
    assert (np.abs(jerk) <= limits.joint_jerk * (1 + 1e-6)).all()


def test_in_limit_velocity_commands_pass_unchanged():
    t = np.arange(2000) * CYCLE
    # a smooth sinusoid: 0.5 rad/s, 1 Hz: acceleration 3.1 rad/s^2, jerk 20 rad/s^3
    cmd = 0.5 * np.sin(2 * np.pi * t)[:, None] * np.ones(7)
    v, a = np.zeros(7), np.zeros(7)
    up, lo = FER_LIMITS.joint_velocity_limits(np.zeros(7))
    for c in cmd:
        out = limit_joint_velocity(c, v, a, up, lo, FER_LIMITS.joint_acceleration, FER_LIMITS.joint_jerk)
        np.testing.assert_allclose(out, c, rtol=0, atol=1e-12)
        a = (out - v) / CYCLE
        v = out


def test_fr3_velocity_commands_stop_before_the_position_limit():
    lim = JointRateLimiter(FR3_LIMITS)
    lim.reset(np.array([2.0, 1.0, 2.0, -0.8, 2.0, 3.5, 2.0]))
    for _ in range(4000):
        lim.velocity(np.full(7, 3.0))  # towards the upper limits, for 4 s
    # where the limit curve's deceleration k/2 is within the acceleration limit (joints 1-4 and 6), the command
    # stops before the limit; joints 5 and 7 (k/2 = 17 rad/s^2 > 10) overshoot it, as libfranka's limiter does
    ok = FR3_LIMITS.velocity_k / 2 <= FR3_LIMITS.joint_acceleration
    np.testing.assert_array_equal(ok, [True, True, True, True, False, True, False])
    assert (lim.q_d[ok] < FR3_LIMITS.q_upper[ok]).all()
    assert (FR3_LIMITS.q_upper[ok] - lim.q_d[ok] < 0.05).all()
    assert (lim.q_d[~ok] > FR3_LIMITS.q_upper[~ok]).all()
    np.testing.assert_allclose(lim.last[ok], 0.0, atol=0.05)


def test_joint_position_is_the_velocity_law_integrated():
    last_q, v, a = np.zeros(7), np.zeros(7), np.zeros(7)
    up, lo = FER_LIMITS.joint_velocity_limits(last_q)
    q = limit_joint_position(np.full(7, 0.1), last_q, v, a, up, lo, FER_LIMITS.joint_acceleration,
                             FER_LIMITS.joint_jerk)
    # from rest the first cycle's jerk is limited: acceleration J dt, position step J dt^3
    np.testing.assert_allclose(q, np.minimum(FER_LIMITS.joint_jerk * CYCLE, FER_LIMITS.joint_acceleration)
                               * CYCLE * CYCLE)


def test_cartesian_velocity_and_pose_respect_the_norm_limits():
    rng = np.random.default_rng(1)
    v, a = np.zeros(6), np.zeros(6)
    vmax_t, amax_t, _ = FER_LIMITS.translation
    vmax_r, amax_r, _ = FER_LIMITS.rotation
    for k in range(2000):
        if k % 50 == 0:
            target = rng.uniform(-5, 5, 6)
        out = limit_cartesian_velocity(target, v, a, FER_LIMITS)
        acc = (out - v) / CYCLE
        assert np.linalg.norm(out[:3]) <= vmax_t + 1e-9 and np.linalg.norm(out[3:]) <= vmax_r + 1e-9
        assert np.linalg.norm(acc[:3]) <= amax_t + 1e-6 and np.linalg.norm(acc[3:]) <= amax_r + 1e-6
        v, a = out, acc
    # a small in-limit twist step from the same twist passes
    np.testing.assert_allclose(limit_cartesian_velocity(v, v, np.zeros(6), FER_LIMITS), v, atol=1e-12)
    # pose: a 10 cm jump is limited to the first cycle's jerk-limited motion, the rotation stays orthonormal
    T0 = np.eye(4)
    T1 = np.eye(4)
    T1[0, 3] = 0.1
    T = limit_cartesian_pose(T1, T0, np.zeros(6), np.zeros(6), FER_LIMITS)
    assert 0 < T[0, 3] <= FER_LIMITS.translation[2] * CYCLE**3 + 1e-15
    np.testing.assert_allclose(T[:3, :3], np.eye(3))
    with pytest.raises(ValueError, match="homogeneous"):
        limit_cartesian_pose(np.ones((4, 4)), T0, np.zeros(6), np.zeros(6))


@pytest.mark.parametrize("robot", ["fer", "fr3"])
@pytest.mark.parametrize("mode", ["velocity", "torque"])
def test_simulated_robot_applies_the_limiter_every_physics_step(robot, mode):
    """FrankaSim(command_rates="limit") runs the limiter once per physics step (in the compiled plant when built):
    the controls are, bit for bit, JointRateLimiter's sequence for the same targets, and a jump never trips."""
    from franka_vs_gym.sim import FORCE_TORQUE, JOINT_STATE, VELOCITY, FrankaSim

    sim = FrankaSim(robot=robot, camera=False, command_rates="limit")
    sim.set_robot_state(VELOCITY if mode == "velocity" else FORCE_TORQUE)
    ref = JointRateLimiter(rate_limits(robot), sim.dt)
    ref.reset(sim.get_position())
    rng = np.random.default_rng(3)
    for k in range(300):
        if k % 60 == 0:
            scale = 0.5 if mode == "velocity" else np.array([3, 3, 3, 3, 0.2, 0.2, 0.05])
            target = rng.uniform(-1, 1, 7) * scale
        # a controller's loop: read the state (forward kinematics), command, step
        sim.get_fMe()
        if mode == "velocity":
            sim.set_velocity(JOINT_STATE, target)
        else:
            sim.set_force_torque(JOINT_STATE, target)
        sim.step()
        expected = ref.velocity(target) if mode == "velocity" else ref.torque(target)
        got = sim._ctrl_vel if mode == "velocity" else sim._ctrl_tau
        np.testing.assert_array_equal(got, expected)
    assert sim.current_errors == ()
