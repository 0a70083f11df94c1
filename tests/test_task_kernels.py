"""The visual tasks' compiled kernels (franka_vs_gym/sim/_task.c) and the compiled step of a torque- or joint-velocity-
action env.

The truth kernel is checked against an independent computation (pinocchio's forward kinematics and log3, the numpy
projection of franka_vs_gym.vision.tags); the compiled step against the general Python path of the same env, bit for
bit, over episodes that end every way an episode can end.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pinocchio as pin
import pytest

import franka_vs_gym  # noqa: F401
from franka_vs_gym.envs import kernels as K
from franka_vs_gym.model.geometry import rot_x, rot_y, rot_z
from franka_vs_gym.policies import IBVSEyeToHandPolicy, IBVSPolicy, PBVSEyeToHandPolicy, PBVSPolicy
from franka_vs_gym.sim import plant
from franka_vs_gym.vision.tags import tag_corners

pytestmark = pytest.mark.skipif(not plant.NATIVE, reason="the compiled plant is not built")


def _records(u, q, fMo, native):
    out = np.zeros((len(q), K.REC))
    geo = u._plan.geo_or_none if native else None
    fMe = None if native else np.array([u.sim.model.fMe(x) for x in q])
    return K.truth_records(geo, np.ascontiguousarray(q), fMo, out, fMe=fMe, eMc=u.sim.get_eMc(),
                           tag_size=u.tag_size, intrinsics=u.intrinsics, features_desired=u.features_desired)


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_truth_kernel_matches_pinocchio_and_the_numpy_projection(robot):
    env = gym.make("FrankaIBVS-v0", robot=robot)
    u = env.unwrapped
    rng = np.random.default_rng(1)
    lim = u.sim.model.limits()
    rows_q, rows_fMo = [], []
    for i in range(12):
        env.reset(seed=i)
        q0 = u.sim.q
        rows_q += [q0 + rng.normal(0, s, 7) for s in (0.0, 0.02, 0.2)] + [rng.uniform(lim["q_min"], lim["q_max"])]
        rows_fMo += [u._fMo.copy()] * 4
    q, fMo = np.array(rows_q), np.array(rows_fMo)
    a = _records(u, q, fMo.reshape(-1, 16), True)
    b = _records(u, q, fMo, False)
    assert np.array_equal(a[:, K.R_VISIBLE], b[:, K.R_VISIBLE])
    assert 0 < a[:, K.R_VISIBLE].sum() < len(a)  # both visible and invisible tags were checked
    np.testing.assert_allclose(a[:, K.R_CMO], b[:, K.R_CMO], rtol=0, atol=1e-13)
    np.testing.assert_allclose(a[:, K.R_DEPTH], b[:, K.R_DEPTH], rtol=0, atol=1e-13)
    np.testing.assert_allclose(a[:, K.R_POSE], b[:, K.R_POSE], rtol=0, atol=1e-9)
    vis = a[:, K.R_VISIBLE] == 1
    np.testing.assert_allclose(a[vis, K.R_FEATURES], b[vis, K.R_FEATURES], rtol=0, atol=1e-12)
    np.testing.assert_allclose(a[:, K.R_ERROR], b[:, K.R_ERROR], rtol=0, atol=1e-12)
    env.close()


def test_pose_vector_kernel_matches_pinocchio_log3_near_zero_and_pi():
    """With an identity chain and camera mount, the record's cMo is fMo itself: its pose vector against
    pinocchio's log3, at small angles, at pi and just below it (the visual tasks' common case: the tag faces the
    camera, a rotation of about pi)."""
    geo = np.zeros(K.GEO)
    for k in range(8):
        geo[12 * k:12 * k + 9] = np.eye(3).ravel()
    geo[96:108] = tag_corners(0.08).ravel()
    geo[108:114] = (300.0, 300.0, 160.0, 120.0, 319.5, 239.5)
    rng = np.random.default_rng(0)
    Rs = [np.eye(3), rot_z(1e-12), rot_x(1e-7) @ rot_y(-3e-8), rot_x(np.pi), rot_y(np.pi), rot_z(np.pi),
          rot_x(np.pi - 1e-9) @ rot_z(0.3), rot_z(0.3) @ rot_x(np.pi - 1e-6), pin.exp3(np.array([1.0, 1.0, 1.0])
                                                                                   / np.sqrt(3) * (np.pi - 1e-10))]
    Rs += [pin.exp3(rng.normal(size=3)) for _ in range(200)]
    fMo = np.zeros((len(Rs), 16))
    for i, R in enumerate(Rs):
        M = np.eye(4)
        M[:3, :3], M[:3, 3] = R, (0.01, -0.02, 0.3)
        fMo[i] = M.ravel()
    out = np.zeros((len(Rs), K.REC))
    plant.tag_truth(geo, np.zeros((len(Rs), 7)), fMo, out)
    for i, R in enumerate(Rs):
        w = out[i, K.R_POSE][3:]
        ref = pin.log3(R)
        if np.linalg.norm(ref) > np.pi - 1e-6:  # at pi, u and -u are the same rotation
            assert np.allclose(pin.exp3(w), R, atol=1e-9), (i, w, ref)
            assert abs(np.linalg.norm(w) - np.linalg.norm(ref)) < 1e-9
        else:
            np.testing.assert_allclose(w, ref, rtol=0, atol=1e-10, err_msg=str(i))


def test_torque_cost_kernel_is_the_sequential_formula():
    rng = np.random.default_rng(0)
    tau_max = np.array([87.0] * 4 + [12.0] * 3)
    tau = rng.uniform(-1, 1, (50, 7)) * tau_max
    out = np.zeros(50)
    plant.torque_cost(tau, tau_max, 0.01, out)
    x = tau / tau_max
    ss = x[:, 0] * x[:, 0]
    for k in range(1, 7):
        ss = ss + x[:, k] * x[:, k]
    assert np.array_equal(out, 0.01 * ss / 7.0)  # the same operations in the same order: the same bits
    np.testing.assert_allclose(out, 0.01 * (x**2).mean(axis=1), rtol=1e-15)
    assert K.torque_penalty(tau[3], tau_max, 0.01) == out[3]


# ---------------------------------------------------------------------------------------------------- env step
def _rollout(env_id, kwargs, policy, steps, compiled, seed=3):
    env = gym.make(env_id, **{"action_scale": "physical", **kwargs})  # (the policies speak Nm)
    u = env.unwrapped
    plan = u._plan
    plan.fast = plan.fast and compiled
    taken = [0]
    if compiled:
        step = plan.step

        def counted(e, a):
            r = step(e, a)
            taken[0] += r is not None
            return r

        plan.step = counted
    out = [env.reset(seed=seed)]
    rng = np.random.default_rng(seed)
    for t in range(steps):
        r = env.step(policy(u, out[-1][0], rng, t))
        out.append(r)
        if r[2] or r[3]:
            out.append(env.reset())
    env.close()
    return out, taken[0]


def _assert_same(x, y, path=""):
    if isinstance(x, dict):
        assert x.keys() == y.keys(), path
        for k in x:
            _assert_same(x[k], y[k], f"{path}/{k}")
    elif isinstance(x, (tuple, list)):
        assert len(x) == len(y), path
        for i, (a, b) in enumerate(zip(x, y, strict=True)):
            _assert_same(a, b, f"{path}[{i}]")
    elif isinstance(x, np.ndarray):
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), (path, x, y)
    else:
        assert type(x) is type(y) and (x == y or (x != x and y != y)), (path, x, y)


def _random(scale):
    def policy(u, obs, rng, t):
        a = (rng.uniform(-1, 1, 7) * scale * u.tau_max).astype(np.float32)
        return a.astype(np.float64) if t % 7 == 3 else a
    return policy


def _towards(delta, ramp=300):
    """Computed-torque joint control to the episode's first posture + delta (rad, reached over ``ramp`` steps)."""
    delta = np.asarray(delta, dtype=float)

    def policy(u, obs, rng, t):
        q, dq = obs["q"].astype(float), obs["dq"].astype(float)
        if u._steps == 0:
            u.q_start_for_test = q.copy()
        target = u.q_start_for_test + delta * min(1.0, u._steps / ramp)
        m = u.sim.model
        tau = m.mass_matrix(q) @ (100.0 * (target - q) - 20.0 * dq) + m.coriolis(q, dq) + m.friction(dq)
        return np.clip(tau, -u.tau_max, u.tau_max).astype(np.float32)
    return policy


def _servo(u, obs, rng, t):
    """Computed-torque velocity loop on a classical IBVS twist (as in tests/test_envs.py): reaches the goal."""
    from franka_vs_gym.model.geometry import inverse_pose
    from franka_vs_gym.sim import twist_transform
    from franka_vs_gym.vision.features import points_interaction_matrix

    model = u.sim.model
    q, dq = obs["q"].astype(float), obs["dq"].astype(float)
    s, sd = obs["features"].astype(float).reshape(4, 2), obs["features_desired"].astype(float).reshape(4, 2)
    L = 0.5 * (points_interaction_matrix(s, obs["feature_depth"].astype(float))
               + points_interaction_matrix(sd, np.full(4, float(obs["tag_pose_desired"][2]))))
    v = np.clip(-1.5 * np.linalg.pinv(L) @ (s - sd).ravel(), [-0.5] * 3 + [-1] * 3, [0.5] * 3 + [1] * 3)
    J = twist_transform(inverse_pose(u.sim.get_eMc())) @ model.eJe(q)
    tau = model.mass_matrix(q) @ (20.0 * (np.linalg.pinv(J) @ v - dq)) + model.coriolis(q, dq) + model.friction(dq)
    return np.clip(tau, -u.tau_max, u.tau_max).astype(np.float32)


def _tracker(u, obs, rng, t):
    """Computed torque on the desired trajectory of the observation: tracks it well enough to succeed."""
    m = u.sim.model
    q, dq = obs["q"].astype(float), obs["dq"].astype(float)
    e, de = obs["q_desired"] - q, obs["dq_desired"] - dq
    tau = m.mass_matrix(q) @ (obs["ddq_desired"] + 400.0 * e + 40.0 * de) + m.coriolis(q, dq) + m.friction(dq)
    return np.clip(tau, -u.tau_max, u.tau_max).astype(np.float32)


def _uniform(u, obs, rng, t):
    """A uniformly random action of the (normalized) action space."""
    return rng.uniform(-1, 1, 7).astype(np.float32)


def _random_velocity(scale):
    """Uniformly random joint velocities, scale x dq_max (physical actions), as float32 or (every 7th) float64."""
    def policy(u, obs, rng, t):
        a = (rng.uniform(-1, 1, 7) * scale * u.dq_max).astype(np.float32)
        return a.astype(np.float64) if t % 7 == 3 else a
    return policy


def _scripted(cls):
    """A scripted visual-servo policy (joint velocities) through the env's action space."""
    def policy(u, obs, rng, t):
        if not hasattr(u, "policy_for_test"):
            u.policy_for_test = cls(model=u.sim.model).with_action_scale(u.action_scale)
        return u.policy_for_test.predict(obs)[0]
    return policy


def _tracker_normalized(u, obs, rng, t):
    """_tracker through the normalized action space (its torque divided by the env's scale)."""
    return u.to_action(_tracker(u, obs, rng, t))


@pytest.mark.parametrize("env_id, kwargs, policy, steps, ends", [
    ("FrankaVisualTorque-v0", {"observation_type": "state"}, _servo, 600, {"success"}),
    ("FrankaVisualTorque-v0", {}, _servo, 600, {"success"}),
    ("FrankaVisualTorque-v0", {}, _random(0.5), 300, {"joint_velocity_violation"}),
    ("FrankaVisualTorque-v0", {}, _towards([0.8, 0, 0, 0, 0, 0, 0], 150), 250, {"tag lost"}),
    ("FrankaVisualTorque-v0", {"terminate_on_tag_lost": False}, _towards([0, 1.5, 0, 0, 0, 1.5, 0]), 250,
     {"collision"}),
    ("FrankaVisualTorque-v0", {"terminate_on_tag_lost": False}, _towards([0, 0, 0, 3.0, 0, 0, 0]), 300,
     {"joint_position_limits_violation"}),
    ("FrankaVisualTorque-v0", {"link_mass_range": (0.8, 1.2), "payload_mass_range": (0.0, 1.0),
                               "friction_scale_range": (0.5, 1.5)}, _random(0.05), 300, set()),
    ("FrankaIBVS-v0", {"action_type": "torque", "control_period": 0.01, "camera_period": 0.03}, _random(0.05), 300,
     set()),
    ("FrankaPBVS-v0", {"action_type": "torque", "control_period": 0.01, "observation_type": "state"},
     _random(0.05), 200, set()),
    ("FrankaTorqueTracking-v0", {}, _tracker, 1100, {"success"}),
    ("FrankaTorqueTracking-v0", {"time_limit": 1.0}, _random(0.3), 300, {"joint_velocity_violation"}),
    ("FrankaTorqueTracking-v0", {"link_mass_range": (0.8, 1.2), "friction_scale_range": (0.5, 1.5),
                                 "time_limit": 1.0, "max_tracking_error": None}, _random(0.02), 300, {"time limit"}),
    # the default interface: normalized actions through the rate limiter (uniformly random: no reflex), and the
    # robot's old interface (physical actions, no limiter)
    ("FrankaVisualTorque-v0", {"action_scale": "normalized"}, _uniform, 600, set()),
    ("FrankaTorqueTracking-v0", {"action_scale": "normalized"}, _uniform, 300, {"tracking lost"}),
    ("FrankaTorqueTracking-v0", {"action_scale": "normalized"}, _tracker_normalized, 600, {"success"}),
    ("FrankaVisualTorque-v0", {"limit_rate": False}, _random(0.5), 300, {"joint_velocity_violation"}),
    ("FrankaTorqueTracking-v0", {"limit_rate": False}, _tracker, 600, {"success"}),
    # joint velocity actions (the visual tasks' default): the limiter and the feed-forward friction in the command
    ("FrankaIBVS-v0", {"action_scale": "normalized"}, _uniform, 400, set()),
    ("FrankaIBVS-v0", {"action_scale": "normalized", "robot": "fr3"}, _uniform, 300, set()),
    ("FrankaPBVS-v0", {"action_scale": "normalized"}, _uniform, 300, set()),
    ("FrankaIBVS-v0", {"action_scale": "normalized"}, _scripted(IBVSPolicy), 400, {"success"}),
    ("FrankaPBVS-v0", {"action_scale": "normalized", "observation_type": "state"}, _scripted(PBVSPolicy), 400,
     {"success"}),
    ("FrankaIBVS-v0", {"limit_rate": False}, _random_velocity(1.0), 300, {"joint_velocity_violation"}),
    ("FrankaIBVS-v0", {"limit_rate": False}, _random_velocity(0.3), 300, set()),
    ("FrankaIBVS-v0", {"action_scale": "normalized", "link_mass_range": (0.8, 1.2), "payload_mass_range": (0.0, 1.0),
                       "friction_scale_range": (0.5, 1.5)}, _uniform, 300, set()),
    # the eye-to-hand tasks (the truth kernel with the tag on the hand, the camera's pose written once per episode)
    ("FrankaIBVSEyeToHand-v0", {"action_scale": "normalized"}, _uniform, 300, set()),
    ("FrankaIBVSEyeToHand-v0", {"action_scale": "normalized"}, _scripted(IBVSEyeToHandPolicy), 300, {"success"}),
    ("FrankaPBVSEyeToHand-v0", {"action_scale": "normalized", "robot": "fr3"}, _scripted(PBVSEyeToHandPolicy), 300,
     {"success"}),
    ("FrankaPBVSEyeToHand-v0", {"action_type": "torque", "control_period": 0.01}, _random(0.05), 200, set()),
])
def test_compiled_step_gives_the_general_paths_bits(env_id, kwargs, policy, steps, ends):
    """Observations, rewards, ends and infos of the compiled step equal the general path's, bit for bit, across
    successes, reflexes, a lost tag, contacts or joint limits, and resets; most steps take the compiled step."""
    a, taken = _rollout(env_id, kwargs, policy, steps, True)
    b, none = _rollout(env_id, kwargs, policy, steps, False)
    assert none == 0
    _assert_same(a, b)
    got = set()
    for r in a:
        if len(r) == 5 and (r[2] or r[3]):
            got.add("success" if r[4]["is_success"] else (r[4]["failure"] or "time limit").split(":")[0])
    assert ends <= got, got
    assert taken >= 0.6 * steps, taken  # (mid-period camera frames and failing steps take the general path)


def test_velocity_step_leaves_another_friction_law_to_the_general_path():
    """Joint velocity actions with a model whose friction is not the sigmoid alone (a viscous term): its
    feed-forward is only computed by the model, so every step takes the general path, with the same results."""
    import dataclasses

    from franka_vs_gym.model.config import resolve_config

    cfg = resolve_config(None, None)
    cfg = dataclasses.replace(cfg, friction=dataclasses.replace(cfg.friction, viscous=np.full(7, 0.05)))
    kw = {"action_scale": "normalized", "model": cfg}
    a, taken = _rollout("FrankaIBVS-v0", kw, _uniform, 60, True)
    b, _ = _rollout("FrankaIBVS-v0", kw, _uniform, 60, False)
    assert taken == 0
    _assert_same(a, b)
    env = gym.make("FrankaIBVS-v0", **kw)
    env.reset(seed=0)
    assert env.unwrapped.sim.feedforward_friction() is None
    assert gym.make("FrankaIBVS-v0").unwrapped.sim.feedforward_friction()[0].shape == (7,)  # the default law
    env.close()


def test_compiled_step_leaves_other_actions_to_the_general_path():
    env = gym.make("FrankaVisualTorque-v0", action_scale="physical")
    ref = gym.make("FrankaVisualTorque-v0", action_scale="physical")
    ref.unwrapped._plan.fast = False
    env.reset(seed=0), ref.reset(seed=0)
    a = [1.0, -2.0, 0.5, 0.0, 0.1, 0.0, -0.2]
    for act in (a, np.array(a, np.float32)[::-1].copy()[::-1], np.array([a]), tuple(a)):
        _assert_same(env.step(act), ref.step(act))
    bad = np.array(a, np.float32)
    bad[1] = 200.0
    with pytest.raises(ValueError, match="outside the action space"):
        env.step(bad)
    bad[1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        env.step(bad)
    _assert_same(env.step(np.array(a, np.float32)), ref.step(np.array(a, np.float32)))


def test_camera_mount_change_mid_episode_moves_the_truth():
    env = gym.make("FrankaVisualTorque-v0", action_scale="physical")
    u = env.unwrapped
    env.reset(seed=0)
    env.step(np.zeros(7, np.float32))
    eMc = u.sim.get_eMc()
    eMc[:3, 3] += (0.01, -0.005, 0.002)
    u.sim.set_eMc(eMc)
    env.step(np.zeros(7, np.float32))
    from franka_vs_gym.envs.kernels import camera_tag_poses

    ref = camera_tag_poses(u.sim.get_fMe()[None], eMc, u._fMo[None])[0]
    np.testing.assert_allclose(u.get_cMo(), ref, atol=1e-13)


def test_tracking_kernel_matches_the_numpy_formulas():
    """FrankaTorqueTracking-v0's desired trajectory and error: the compiled kernel (the single env's and the batched
    env's) against kernels.tracking_desired and row_norm in numpy."""
    rng = np.random.default_rng(0)
    n = 40
    q0, A, w = rng.uniform(-2, 2, (n, 7)), rng.uniform(-0.6, 0.6, (n, 7)), rng.uniform(1, 4, (n, 7))
    t, q = rng.uniform(0, 6, n), rng.uniform(-2, 2, (n, 7))
    desired, err = np.zeros((n, 21)), np.zeros(n)
    plant.tracking(q0, A, w, t, q, desired, err)
    qd, dqd, ddqd = K.tracking_desired(q0, A, w, t[:, None])
    np.testing.assert_allclose(desired[:, :7], qd, rtol=0, atol=1e-15)
    np.testing.assert_allclose(desired[:, 7:14], dqd, rtol=1e-15, atol=1e-15)
    np.testing.assert_allclose(desired[:, 14:], ddqd, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(err, K.row_norm(q - qd), rtol=1e-15)
    with pytest.raises(ValueError, match="desired has"):
        plant.tracking(q0, A, w, t, q, np.zeros((n, 20)), err)


@pytest.mark.parametrize("compiled", [True, False])
def test_state_observation_of_a_reflex_stop_is_the_braked_state(compiled):
    """A step that a reflex ends reports the ground truth of the state the brakes hold (computed here from the
    joint positions with pinocchio and the numpy projection), also when a camera frame was taken at the end of the
    previous period."""
    env = gym.make("FrankaVisualTorque-v0", observation_type="state", action_scale="physical")
    u = env.unwrapped
    u._plan.fast = u._plan.fast and compiled
    rng = np.random.default_rng(5)
    stops = 0
    env.reset(seed=5)
    for _ in range(400):
        obs, _, term, trunc, info = env.step((rng.uniform(-1, 1, 7) * 0.3 * u.tau_max).astype(np.float32))
        if term and "reflex" in info:
            ref = _records(u, u.sim.q[None], u._fMo[None], False)[0]
            if ref[K.R_VISIBLE]:
                np.testing.assert_allclose(obs["features"], ref[K.R_FEATURES], atol=1e-6)
                np.testing.assert_allclose(obs["tag_pose"][:3], ref[K.R_POSE][:3], atol=1e-6)
                stops += 1
        if term or trunc:
            env.reset()
    assert stops >= 10, stops
    env.close()


def test_kernels_refuse_wrong_buffers_with_an_error():
    """Wrong sizes or types give a Python error naming the argument, never a write outside a buffer."""
    env = gym.make("FrankaVisualTorque-v0", action_scale="physical")
    u = env.unwrapped
    env.reset(seed=0)
    plan = u._plan
    with pytest.raises(ValueError, match="out has"):
        plant.tag_truth(plan.geo, np.zeros((2, 7)), np.zeros((2, 16)), np.zeros((1, K.REC)))
    with pytest.raises(TypeError, match="q must be a float64"):
        plant.tag_truth(plan.geo, np.zeros((1, 7), np.float32), np.zeros((1, 16)), np.zeros((1, K.REC)))
    out = np.empty(plan.size, np.float32)
    with pytest.raises(ValueError, match="wrong size"):
        plant.visual_post(plan.P[:-1], plan.I, plan.m_addr, plan.d_addr, out, 0)
    bad_i = plan.I.copy()
    bad_i[16] = plan.size  # the offset of q past the observation's end
    with pytest.raises(ValueError, match="layout"):
        plant.visual_post(plan.P, bad_i, plan.m_addr, plan.d_addr, out, 0)
    with pytest.raises(ValueError, match="float32 vector"):
        plant.visual_post(plan.P, plan.I, plan.m_addr, plan.d_addr, out[:-1], 0)
    tau_cmd, tau_applied = u.sim.torque_command_views()
    assert plant.visual_pre(plan.P, plan.I, plan.d_addr, [0.0] * 7, tau_cmd, tau_applied) == -1
    assert plant.visual_pre(plan.P, plan.I, plan.d_addr, np.zeros(6), tau_cmd, tau_applied) == -1
    assert plant.visual_pre(plan.P, plan.I, plan.d_addr, np.zeros(7, np.int64), tau_cmd, tau_applied) == -1
    with pytest.raises(ValueError, match="too short"):
        plant.visual_pre(plan.P[:10], plan.I, plan.d_addr, np.zeros(7), tau_cmd, tau_applied)
    env.close()


def test_a_deep_copy_runs_the_compiled_step_on_its_own_physics():
    import copy

    env = gym.make("FrankaVisualTorque-v0", action_scale="physical")
    u = env.unwrapped
    env.reset(seed=0)
    u.step(np.zeros(7, np.float32))
    twin = copy.deepcopy(u)
    q, ctrl = u.sim.q, u.world.data.ctrl.copy()
    a = np.full(7, 0.5, np.float32)
    r2 = [twin.step(a) for _ in range(6)]
    assert np.array_equal(u.sim.q, q) and np.array_equal(u.world.data.ctrl, ctrl)  # the original is untouched
    r1 = [u.step(a) for _ in range(6)]
    _assert_same(r1, r2)
    assert not np.array_equal(r1[-1][0]["q"], r1[0][0]["q"])  # (the torque moved the arm)
    env.close()


def test_compiled_end_is_taken_only_for_the_evaluation_it_stands_for():
    """The IBVS tasks' compiled steps end in one call (FrankaIBVSEnv._end_compiled, checked bit for bit against the
    general path above); a subclass with its own evaluation ends them through its _evaluate."""
    from franka_vs_gym.envs.visual_torque import FrankaVisualTorqueEnv

    for env_id, expected in (("FrankaIBVS-v0", True), ("FrankaVisualTorque-v0", True),
                             ("FrankaIBVSEyeToHand-v0", True), ("FrankaPBVS-v0", False)):
        env = gym.make(env_id)
        assert env.unwrapped._plan.task_end is expected, env_id
        env.close()

    class Shaped(FrankaVisualTorqueEnv):
        def _evaluate(self, action):
            reward, success, failure, info = super()._evaluate(action)
            return reward - 5.0, success, failure, info

    shaped, plain = Shaped(), FrankaVisualTorqueEnv()
    assert not shaped._plan.task_end and plain._plan.task_end
    shaped._plan.fast = True  # (a class outside the package takes the general path; its compiled step here)
    shaped.reset(seed=2)
    plain.reset(seed=2)
    a = np.zeros(7, np.float32)
    for _ in range(3):
        rs, rp = shaped.step(a), plain.step(a)
        assert rs[1] == rp[1] - 5.0
