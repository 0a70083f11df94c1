"""The environments' action interface: normalized action spaces with a documented physical scale, the robot
interface's rate limiter on by default, and a uniformly random policy that ends (almost) no episode by a reflex,
while the robot's old interface (physical actions, no limiter) trips one in most episodes."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest

import franka_vs_gym
from franka_vs_gym.envs.base import torque_action_scale
from franka_vs_gym.envs.registration import ENVS
from franka_vs_gym.model.config import resolve_config
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.policies import IBVSPolicy

REFLEXES = ("joint_position_limits_violation", "joint_velocity_violation", "tau_J_range_violation")


def _random_episodes(env_id, robot, n, **kwargs):
    """How n uniformly random episodes end: (reflex count, failure reasons)."""
    env = gym.make(env_id, robot=robot, **kwargs)
    reflex, ends = 0, []
    for i in range(n):
        env.reset(seed=100 + i)
        env.action_space.seed(100 + i)
        while True:
            _, _, term, trunc, info = env.step(env.action_space.sample())
            if term or trunc:
                break
        f = info.get("failure") or ("success" if info.get("is_success") else "time limit")
        reflex += f.split(",")[0] in REFLEXES
        ends.append(f.split(":")[0])
    env.close()
    return reflex, ends


@pytest.mark.parametrize("robot", ["fer", "fr3"])
@pytest.mark.parametrize("env_id", list(ENVS))
def test_random_policy_rarely_ends_by_a_reflex(env_id, robot):
    reflex, ends = _random_episodes(env_id, robot, 6)
    assert reflex == 0, ends  # (scripts/random_policy.py: <= 5 % over 100 episodes; 0-3 % measured)
    if robot == "fer":  # the robot's old interface: a reflex in most episodes
        before, ends = _random_episodes(env_id, robot, 3, action_scale="physical", limit_rate=False)
        assert before >= 2, ends


@pytest.mark.parametrize("env_id", list(ENVS))
def test_default_spaces_are_normalized_and_pass_the_checkers(env_id):
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = gym.make(env_id)
    u = env.unwrapped
    assert env.action_space.low.min() == -1.0 and env.action_space.high.max() == 1.0
    assert u.action_scale.shape == env.action_space.shape and (u.action_scale > 0).all()
    assert (u.action_scale <= u.physical_action_bounds).all()
    np.testing.assert_allclose(u.to_physical(np.ones(env.action_space.shape)), u.action_scale)
    np.testing.assert_allclose(u.to_physical(u.to_action(0.5 * u.action_scale)), 0.5 * u.action_scale, rtol=1e-6)
    with warnings.catch_warnings():
        warnings.simplefilter("error", category=UserWarning)  # no "symmetric and normalized space" warning now
        warnings.filterwarnings("ignore", message=".*Box observation space.*unbounded.*")
        gym_check(u, skip_render_check=True)
        sb3_check(u, warn=True)
    phys = gym.make(env_id, action_scale="physical")
    np.testing.assert_allclose(phys.action_space.high, u.physical_action_bounds.astype(np.float32))
    assert phys.unwrapped.action_scale is None
    env.close()
    phys.close()


def test_torque_scale_is_the_inertia_and_friction_formula():
    """The documented torque scale, recomputed here from the mass matrix (pinocchio CRBA) and the friction law."""
    import pinocchio as pin

    model = FrankaModel(resolve_config(None, "fer"))
    q = model.robot.neutral()
    M = pin.crba(model.model, model.model.createData(), q)
    M = np.triu(M) + np.triu(M, 1).T
    expected = np.minimum(np.abs(M).sum(axis=1) * 2.0 + np.abs(model.friction(np.full(7, 0.3))), 87.0)
    np.testing.assert_allclose(torque_action_scale(model, 2.0, 0.3), np.minimum(expected, model.limits()["tau_max"]),
                               rtol=1e-12)
    env = gym.make("FrankaTorqueTracking-v0", amplitude=0.2, frequency_range=(0.2, 0.4))
    w = 2 * np.pi * 0.4
    np.testing.assert_allclose(env.unwrapped.action_scale, torque_action_scale(model, 0.2 * w * w, 0.2 * w))


def test_the_limiter_alone_keeps_in_space_velocity_actions_from_tripping():
    """The issue's case: random joint velocities over the robot's whole range (physical units), 2 s episodes.
    Without the limiter the proportional servo's transients between held actions exceed the velocity limit
    (joint_velocity_violation in every episode); through the limiter no episode ends by a reflex."""
    for limit, expect in ((False, 4), (True, 0)):
        env = gym.make("FrankaIBVS-v0", action_scale="physical", limit_rate=limit, terminate_on_tag_lost=False,
                       time_limit=2.0)
        reflex, ends = 0, []
        for i in range(4):
            env.reset(seed=100 + i)
            env.action_space.seed(100 + i)
            while True:
                _, _, term, trunc, info = env.step(env.action_space.sample())
                if term or trunc:
                    break
            reflex += info.get("failure") in REFLEXES
            ends.append(info.get("failure"))
        env.close()
        assert reflex == expect, (limit, ends)


def test_scripted_policies_act_through_the_normalized_space():
    env = gym.make("FrankaIBVS-v0")
    res = franka_vs_gym.evaluate(IBVSPolicy(), env, 3, seed=0)  # (evaluate binds it to the env's scale)
    assert res["success_rate"] == 1.0, res["failures"]
    bound = IBVSPolicy().with_action_scale(env.unwrapped.action_scale)
    obs, _ = env.reset(seed=0)
    a, _ = bound.predict(obs)
    assert env.action_space.contains(a)
    env.close()


@pytest.mark.parametrize("kwargs, match", [({"action_scale": "meters"}, "action_scale"),
                                           ({"action_scale": 100.0}, "within the robot's limits"),
                                           ({"action_scale": -1.0}, "> 0"),
                                           ({"action_scale": [1.0, 2.0]}, "action_scale"),
                                           ({"limit_rate": "yes"}, "limit_rate"),
                                           ({"joint_limit_guard": "on"}, "joint_limit_guard")])
def test_bad_action_options_are_clear_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gym.make("FrankaIBVS-v0", **kwargs)


def _joint_limit_ends(ends):
    return sum(e.startswith("joint limit") or e.split(",")[0] == "joint_position_limits_violation" for e in ends)


def test_joint_limit_guard_keeps_random_exploration_off_the_limits():
    """The eye-to-hand starts lie near joint limits: uniformly random joint velocities ran about a third of the FR3's
    episodes into a joint limit before the guard (scripts/random_policy.py); with it (the default) none."""
    _, off = _random_episodes("FrankaIBVSEyeToHand-v0", "fr3", 16, joint_limit_guard=False)
    _, on = _random_episodes("FrankaIBVSEyeToHand-v0", "fr3", 16)
    assert _joint_limit_ends(off) >= 3, off
    assert _joint_limit_ends(on) == 0, on


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_joint_limit_guard_brakes_before_the_bound_and_releases_away_from_it(robot):
    """A joint driven at full speed into its limit comes to rest inside the task's bound (no failure, no reflex),
    the other joints untouched; driven back, it leaves at full speed at once."""
    env = gym.make("FrankaTorqueTracking-v0", robot=robot, action_type="joint_velocity", max_tracking_error=None,
                   control_period=0.05, time_limit=10.0)
    u = env.unwrapped
    env.reset(seed=0)
    a = np.zeros(7, dtype=np.float32)
    a[0] = 1.0
    for _ in range(80):  # 4 s at the action scale: 4 rad of travel asked for, about 2.5 rad of room
        _, _, term, trunc, info = env.step(a)
        assert not term, info["failure"]
    q = u.sim.q
    assert u._q_hi_fail[0] - 0.05 < q[0] < u._q_hi_fail[0]
    assert abs(u.sim.dq[0]) < 0.05
    a[0] = -1.0
    for _ in range(6):
        env.step(a)
    assert u.sim.dq[0] < -0.9 * u.action_scale[0]
    env.close()
