"""Environment suite: peer checkers (Gymnasium, stable-baselines3), determinism, vector envs, action handling,
divergence, physical behaviour of the three action types, camera timing, randomisation, evaluate()."""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import franka_vs_gym
from franka_vs_gym.envs.registration import ENVS


def _env_class(env_id):
    return gym.envs.registration.load_env_creator(ENVS[env_id])


def _visual_ids():
    from franka_vs_gym.envs.visual import VisualServoEnv

    return [env_id for env_id in sorted(ENVS) if issubclass(_env_class(env_id), VisualServoEnv)]


VISUAL = _visual_ids()  # read from the registry: every visual-servoing task
SMALL_IMAGE = {"image_width": 48, "image_height": 36}  # SB3's CnnPolicy minimum is 36x36


def combos():
    """Every registered environment with every action and observation type its class supports."""
    for env_id in sorted(ENVS):
        cls = _env_class(env_id)
        for act in cls.supported_action_types:
            for obs in cls.supported_observation_types:
                yield env_id, act, obs


def make(env_id, **kw):
    if env_id in VISUAL and "image" in kw.get("observation_type", "features"):
        kw = {**SMALL_IMAGE, **kw}
    return gym.make(env_id, **kw)


def test_all_ids_registered_on_import():
    for env_id in ENVS:
        assert env_id in gym.registry
    assert set(ENVS) == {"FrankaIBVS-v0", "FrankaPBVS-v0", "FrankaTorqueTracking-v0", "FrankaVisualTorque-v0",
                         "FrankaIBVSEyeToHand-v0", "FrankaPBVSEyeToHand-v0"}
    assert franka_vs_gym.evaluate is franka_vs_gym.envs.evaluate


@pytest.mark.parametrize("env_id,action_type,observation_type", list(combos()))
def test_peer_checkers(env_id, action_type, observation_type):
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = make(env_id, action_type=action_type, observation_type=observation_type)
    with warnings.catch_warnings():
        warnings.simplefilter("error", category=UserWarning)  # Gymnasium's checker warns on contract problems
        warnings.filterwarnings("ignore", message=".*symmetric and normalized space.*")
        warnings.filterwarnings("ignore", message=".*Box observation space.*unbounded.*")
        gym_check(env.unwrapped, skip_render_check=True)
    sb3_check(env.unwrapped, warn=True)
    # observations stay inside their space along a short rollout of random actions
    env.action_space.seed(0)
    obs, _ = env.reset(seed=1)
    for _ in range(3):
        obs, r, term, trunc, info = env.step(env.action_space.sample() * 0.05)
        assert env.observation_space.contains(obs), {k: v for k, v in obs.items()
                                                     if not env.observation_space[k].contains(v)}
        assert math.isfinite(r)
        if term or trunc:
            obs, _ = env.reset()
    env.close()


@pytest.mark.parametrize("env_id", ["FrankaIBVS-v0"])  # the detection path is shared by the visual tasks
def test_peer_checkers_with_detected_features(env_id):
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = make(env_id, feature_source="detection", observation_type="features+image")
    gym_check(env.unwrapped, skip_render_check=True)
    sb3_check(env.unwrapped, warn=False)
    env.close()


def test_render_rgb_array():
    env = make("FrankaIBVS-v0", render_mode="rgb_array", render_width=64, render_height=48)
    env.reset(seed=0)
    img = env.render()
    assert img.shape == (48, 64, 3) and img.dtype == np.uint8 and img.std() > 1.0
    env.close()
    from gymnasium.utils.env_checker import check_env as gym_check

    env = make("FrankaTorqueTracking-v0", render_mode="rgb_array", render_width=32, render_height=24)
    gym_check(env.unwrapped)
    env.close()


def _rollout(env, seed, n=15, scale=0.2):
    env.action_space.seed(seed)
    obs, _ = env.reset(seed=seed)
    traj = [obs]
    rewards = []
    for _ in range(n):
        obs, r, term, trunc, info = env.step(env.action_space.sample() * scale)
        traj.append(obs)
        rewards.append(r)
        if term or trunc:
            break
    return traj, rewards


@pytest.mark.parametrize("env_id", list(ENVS))
def test_same_seed_same_trajectory(env_id):
    kw = dict(joint_noise=1e-3, velocity_noise=1e-3, link_mass_range=(0.9, 1.1), friction_scale_range=(0.8, 1.2),
              payload_mass_range=(0.0, 0.5))
    if env_id in VISUAL:
        kw["feature_noise"] = 0.5
    a, b = make(env_id, **kw), make(env_id, **kw)
    ta, ra = _rollout(a, 3)
    tb, rb = _rollout(b, 3)
    assert len(ta) == len(tb) and ra == rb
    for oa, ob in zip(ta, tb, strict=True):
        for k in oa:
            np.testing.assert_array_equal(oa[k], ob[k], err_msg=k)
    tc, _ = _rollout(a, 4)  # another seed gives another episode
    assert not np.array_equal(ta[0]["q"], tc[0]["q"])


def test_vector_envs_sync_and_async_agree():
    kw = {"observation_type": "features"}
    fns = [lambda: gym.make("FrankaIBVS-v0", **kw) for _ in range(2)]
    sync, asyn = gym.vector.SyncVectorEnv(fns), gym.vector.AsyncVectorEnv(fns)
    try:
        os_, _ = sync.reset(seed=5)
        oa, _ = asyn.reset(seed=5)
        np.testing.assert_array_equal(os_["features"], oa["features"])
        assert os_["q"].shape == (2, 7)
        assert not np.array_equal(os_["q"][0], os_["q"][1])  # seeds 5 and 6
        rng = np.random.default_rng(0)
        for _ in range(5):
            act = (rng.uniform(-0.2, 0.2, (2, 7))).astype(np.float32)
            os_, rs, *_ = sync.step(act)
            oa, ra, *_ = asyn.step(act)
            np.testing.assert_array_equal(os_["q"], oa["q"])
            np.testing.assert_array_equal(rs, ra)
    finally:
        sync.close()
        asyn.close()


def test_async_vector_env_with_images():
    """Image observations in worker processes. A process that has rendered holds an OpenGL context that a forked
    worker cannot reuse, so with images the workers are spawned; 'franka_vs_gym:Id' makes them import the package
    (and its registrations) first."""
    fns = [lambda: gym.make("franka_vs_gym:FrankaIBVS-v0", observation_type="features+image", image_width=48,
                            image_height=36) for _ in range(2)]
    venv = gym.vector.AsyncVectorEnv(fns, context="spawn")
    try:
        obs, _ = venv.reset(seed=0)
        assert obs["image"].shape == (2, 36, 48, 3) and obs["image"].std() > 1.0
        obs, *_ = venv.step(np.zeros((2, 7), np.float32))
        assert obs["features"].shape == (2, 8)
    finally:
        venv.close()


def test_module_prefixed_id_for_spawned_workers():
    """'franka_vs_gym:FrankaIBVS-v0' imports the package first (what spawned worker processes need)."""
    env = gym.make("franka_vs_gym:FrankaIBVS-v0")
    env.reset(seed=0)
    env.close()
    res = franka_vs_gym.evaluate(lambda o: np.zeros(7, np.float32), "franka_vs_gym:FrankaIBVS-v0", 1,
                                 env_kwargs={"time_limit": 0.2})
    assert res["n_episodes"] == 1


@pytest.mark.parametrize("action_type", ["torque", "joint_velocity", "cartesian_velocity"])
def test_bad_actions_raise_clear_errors(action_type):
    env = make("FrankaIBVS-v0", action_type=action_type)
    env.reset(seed=0)
    n = env.action_space.shape[0]
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.full(n, np.nan, np.float32))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.array([np.inf] + [0.0] * (n - 1)))
    big = np.zeros(n, np.float32)
    big[0] = env.action_space.high[0] * 2
    with pytest.raises(ValueError, match="outside the action space"):
        env.step(big)
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(n + 1))
    # nothing reached the robot: the state is still finite and the env usable
    obs, *_ = env.step(np.zeros(n, np.float32))
    assert all(np.isfinite(v).all() for v in obs.values())
    env.close()


def test_clip_actions_option_clips():
    env = make("FrankaIBVS-v0", action_type="joint_velocity", clip_actions=True)
    env.reset(seed=0)
    a = np.zeros(7, np.float32)
    a[6] = 50.0  # rad/s, far beyond 2.61
    env.step(a)
    dq = env.unwrapped.sim.get_velocity()
    assert abs(dq[6]) <= 2.61 * 1.05
    env.close()


@pytest.mark.parametrize("kwargs,match", [
    ({"action_type": "velocity"}, "action_type"),
    ({"observation_type": "pixels"}, "observation_type"),
    ({"control_period": 0.0505}, "whole multiple"),
    ({"camera_period": -1}, "camera_period"),
    ({"tag_size": 0}, "tag_size"),
    ({"link_mass_range": (1.2, 0.8)}, "link_mass_range"),
    ({"feature_source": "magic"}, "feature_source"),
    ({"model": "/nonexistent/model.json"}, "not found"),
])
def test_bad_options_raise(kwargs, match):
    with pytest.raises((ValueError, FileNotFoundError), match=match):
        gym.make("FrankaIBVS-v0", **kwargs)


def test_unsupported_render_mode_raises():
    from franka_vs_gym.envs.ibvs import FrankaIBVSEnv

    with pytest.raises(ValueError, match="render_mode"):
        FrankaIBVSEnv(render_mode="human")


def test_tracking_rejects_camera_observations():
    with pytest.raises(ValueError, match="observation_type"):
        gym.make("FrankaTorqueTracking-v0", observation_type="features")
    with pytest.raises(ValueError, match="action_type"):
        gym.make("FrankaTorqueTracking-v0", action_type="cartesian_velocity")


def test_divergence_ends_episode_with_reason():
    env = make("FrankaTorqueTracking-v0", action_scale="physical")
    obs0, _ = env.reset(seed=0)
    u = env.unwrapped
    u.world.model.opt.timestep = 5.0  # sabotage the integrator: 5 s steps blow up
    u.world.model.dof_armature[:] = 0.0
    action = np.array([87, -87, 87, -87, 12, -12, 12], np.float32)
    for _ in range(200):
        obs, r, term, trunc, info = env.step(action)
        if term:
            break
    assert term and info["failure"].startswith("diverged"), info
    assert all(np.isfinite(v).all() for v in obs.values()) and math.isfinite(r)
    with pytest.raises(RuntimeError, match="diverged"):
        env.step(np.zeros(7, np.float32))
    u.world.model.opt.timestep = 0.001
    obs, _ = env.reset(seed=1)
    assert all(np.isfinite(v).all() for v in obs.values())
    env.close()


def test_joint_velocity_action_is_tracked():
    env = make("FrankaIBVS-v0", action_type="joint_velocity", terminate_on_tag_lost=False, action_scale="physical")
    env.reset(seed=0)
    cmd = np.array([0.1, -0.1, 0.05, 0.1, -0.1, 0.1, 0.2], np.float32)
    for _ in range(3):
        obs, *_ = env.step(cmd)
    np.testing.assert_allclose(obs["dq"], cmd, atol=0.01)
    env.close()


def test_cartesian_velocity_moves_camera_along_its_axis():
    env = make("FrankaIBVS-v0", action_type="cartesian_velocity", observation_type="state", action_scale="physical")
    obs, _ = env.reset(seed=0)
    u = env.unwrapped
    fMc0 = u.sim.get_fMc()
    z0 = obs["tag_pose"][2]
    for _ in range(10):  # 0.5 s at 0.04 m/s towards the tag
        obs, *_ = env.step(np.array([0, 0, 0.04, 0, 0, 0], np.float32))
    d = fMc0[:3, :3].T @ (u.sim.get_fMc()[:3, 3] - fMc0[:3, 3])  # displacement in the start camera frame
    assert d[2] == pytest.approx(0.02, abs=0.002) and np.hypot(d[0], d[1]) < 0.002
    assert obs["tag_pose"][2] == pytest.approx(z0 - 0.02, abs=0.002)
    env.close()


def test_zero_torque_holds_the_arm_and_undeclared_payload_sags():
    """Torques are gravity-free: zero torque holds the arm; an undeclared payload is not compensated."""
    env = make("FrankaTorqueTracking-v0")
    obs, _ = env.reset(seed=0)
    q0 = obs["q"].copy()
    for _ in range(50):
        obs, *_ = env.step(np.zeros(7, np.float32))
    assert np.abs(obs["q"] - q0).max() < 0.01
    env.close()
    env = make("FrankaTorqueTracking-v0", payload_mass_range=(2.0, 2.0), payload_declared=False)
    obs, info = env.reset(seed=0)
    assert info["payload_mass"] == 2.0
    q0 = obs["q"].copy()
    for _ in range(50):
        obs, *_ = env.step(np.zeros(7, np.float32))
    assert np.abs(obs["q"] - q0).max() > 0.05
    env.close()


def test_link_mass_randomisation_changes_the_plant():
    env = make("FrankaTorqueTracking-v0", link_mass_range=(0.5, 1.5))
    u = env.unwrapped
    m = u.world.model
    links = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{u.sim.prefix}link{i + 1}") for i in range(7)]
    nominal = m.body_mass[links].copy()  # as built, before the first reset draws
    _, info = env.reset(seed=0)
    np.testing.assert_allclose(u.world.model.body_mass[links], nominal * info["link_mass_scale"])
    assert np.all((info["link_mass_scale"] >= 0.5) & (info["link_mass_scale"] <= 1.5))
    _, info2 = env.reset(seed=1)
    assert not np.allclose(info["link_mass_scale"], info2["link_mass_scale"])
    env.close()


def test_model_file_is_used(tmp_path):
    from franka_vs_gym.model import ModelConfig

    cfg = ModelConfig(armature=np.full(7, 0.123))
    path = cfg.save(tmp_path / "calibrated.json")
    env = gym.make("FrankaTorqueTracking-v0", model=str(path))
    u = env.unwrapped
    np.testing.assert_allclose(u.world.model.dof_armature[u.sim.dof_slice], 0.123)
    np.testing.assert_allclose(u.sim.model.config.armature, 0.123)
    env.close()


def test_camera_period_holds_features_between_frames():
    env = make("FrankaIBVS-v0", control_period=0.02, camera_period=0.06, action_type="cartesian_velocity")
    obs, _ = env.reset(seed=0)
    feats = [obs["features"].copy()]
    for _ in range(6):
        obs, *_ = env.step(np.array([0.05, 0, 0, 0, 0, 0], np.float32))
        feats.append(obs["features"].copy())
    changed = [not np.array_equal(feats[i], feats[i - 1]) for i in range(1, 7)]
    # frames at t = 0.06 and 0.12 s: steps 3 and 6 (times 0.06, 0.12) see new features, the others hold
    assert changed == [False, False, True, False, False, True]
    env.close()


def test_tag_lost_is_a_failure():
    env = make("FrankaIBVS-v0", action_type="cartesian_velocity")
    env.reset(seed=0)
    for _ in range(100):
        obs, r, term, trunc, info = env.step(np.array([0.4, 0, 0, 0, 0, 0], np.float32))
        if term or trunc:
            break
    assert term and not info["is_success"] and info["failure"].startswith("tag lost")
    assert r < -1.0  # the failure penalty
    env.close()


def test_tracking_success_with_computed_torque_and_zero_fails():
    from franka_vs_gym.control import ComputedTorque
    from franka_vs_gym.model import FrankaModel

    ct = ComputedTorque(FrankaModel())

    def policy(o):
        tau = ct(float(o["time"][0]), *(o[k].astype(float) for k in ("q", "dq", "q_desired", "dq_desired",
                                                                     "ddq_desired")))
        return np.clip(tau, -env.unwrapped.tau_max, env.unwrapped.tau_max)

    env = gym.make("FrankaTorqueTracking-v0", time_limit=1.0, action_scale="physical")
    policy.reset = ct.reset  # type: ignore[attr-defined]
    good = franka_vs_gym.evaluate(policy, env, 2, seed=0)
    bad = franka_vs_gym.evaluate(lambda o: np.zeros(7, np.float32), env, 2, seed=0)
    assert good["success_rate"] == 1.0 and good["median_final_error"] < 0.01
    assert bad["success_rate"] == 0.0 and bad["mean_return"] < good["mean_return"]
    env.close()


def test_evaluate_rejects_bad_input():
    with pytest.raises(ValueError, match="unknown environment id"):
        franka_vs_gym.evaluate(lambda o: o, "NoSuchEnv-v0", 1)
    with pytest.raises(ValueError, match="n_episodes"):
        franka_vs_gym.evaluate(lambda o: o, "FrankaIBVS-v0", 0)
    with pytest.raises(TypeError, match="policy"):
        franka_vs_gym.evaluate(42, "FrankaIBVS-v0", 1)


def _ibvs_twist(obs, gain=1.5):
    """Classical IBVS camera twist from the contract observation (independent of the env's reward code)."""
    from franka_vs_gym.vision.features import points_interaction_matrix

    s = obs["features"].astype(float).reshape(4, 2)
    sd = obs["features_desired"].astype(float).reshape(4, 2)
    L = 0.5 * (points_interaction_matrix(s, obs["feature_depth"].astype(float))
               + points_interaction_matrix(sd, np.full(4, float(obs["tag_pose_desired"][2]))))
    return -gain * np.linalg.pinv(L) @ (s - sd).ravel()


def test_visual_torque_is_solvable_by_a_dynamic_visual_servo():
    """IBVS camera twist -> joint velocity reference -> computed-torque velocity loop at 200 Hz reaches the goal:
    the torque task, its gravity-free convention and its success condition fit together."""
    from franka_vs_gym.model.geometry import inverse_pose
    from franka_vs_gym.sim import twist_transform

    env = gym.make("FrankaVisualTorque-v0", observation_type="state", action_scale="physical")
    u = env.unwrapped
    model = u.sim.model
    eMc = u.sim.get_eMc()

    def policy(obs):
        q, dq = obs["q"].astype(float), obs["dq"].astype(float)
        v = np.clip(_ibvs_twist(obs), [-0.5] * 3 + [-1] * 3, [0.5] * 3 + [1] * 3)
        J = twist_transform(inverse_pose(eMc)) @ model.eJe(q)
        dq_ref = np.linalg.pinv(J) @ v
        tau = model.mass_matrix(q) @ (20.0 * (dq_ref - dq)) + model.coriolis(q, dq) + model.friction(dq)
        return np.clip(tau, -u.tau_max, u.tau_max).astype(np.float32)

    res = franka_vs_gym.evaluate(policy, env, 3, seed=0)
    assert res["success_rate"] == 1.0, res["episodes"]
    assert res["mean_time_to_converge"] < 5.0
    zero = franka_vs_gym.evaluate(lambda o: np.zeros(7, np.float32), env, 1, seed=0)
    assert zero["success_rate"] == 0.0
    env.close()


@pytest.mark.parametrize("env_id", ["FrankaIBVS-v0", "FrankaPBVS-v0"])
def test_visual_servo_tasks_are_solvable_with_camera_twists(env_id):
    env = gym.make(env_id, action_type="cartesian_velocity", action_scale="physical")
    res = franka_vs_gym.evaluate(
        lambda o: np.clip(_ibvs_twist(o), [-0.5] * 3 + [-1] * 3, [0.5] * 3 + [1] * 3).astype(np.float32), env, 5,
        seed=0)
    assert res["success_rate"] == 1.0, res["episodes"]
    env.close()


def test_detection_features_agree_with_ideal_features():
    ideal = gym.make("FrankaIBVS-v0")
    det = gym.make("FrankaIBVS-v0", feature_source="detection")
    for seed in (0, 1):
        oi, _ = ideal.reset(seed=seed)
        od, _ = det.reset(seed=seed)
        assert od["visible"][0] == 1.0
        # within ~1 pixel of the 320x240 camera (fx = 208 px)
        np.testing.assert_allclose(od["features"], oi["features"], atol=3.0 / 208)
        np.testing.assert_allclose(od["tag_pose"][:3], oi["tag_pose"][:3], atol=0.005)
    obs, *_ = det.step(np.zeros(7, np.float32))
    assert det.observation_space.contains(obs)
    ideal.close()
    det.close()


def test_feature_noise_is_in_pixels():
    env = gym.make("FrankaIBVS-v0", feature_noise=2.0)
    clean = gym.make("FrankaIBVS-v0")
    diffs = []
    for seed in range(20):
        o, _ = env.reset(seed=seed)
        c, _ = clean.reset(seed=seed)
        diffs.append((o["features"] - c["features"]) * env.unwrapped.intrinsics.fx)
    assert np.std(diffs) == pytest.approx(2.0, rel=0.2)
    env.close()
    clean.close()


def test_declared_payload_is_compensated_like_set_load():
    """A declared payload: the robot holds it at zero torque, and the measured joint torques grow by its gravity
    torque as computed independently by the pinocchio model with the same payload."""
    from franka_vs_gym.envs.base import PAYLOAD_COM
    from franka_vs_gym.model import FrankaModel

    env = make("FrankaTorqueTracking-v0", payload_mass_range=(1.5, 1.5))
    bare = make("FrankaTorqueTracking-v0")
    obs, info = env.reset(seed=0)
    bare.reset(seed=0)
    assert info["payload_mass"] == 1.5
    for _ in range(20):
        obs, *_ = env.step(np.zeros(7, np.float32))
        bare.step(np.zeros(7, np.float32))
    q = env.unwrapped.sim.get_position()
    assert np.abs(q - bare.unwrapped.sim.get_position()).max() < 1e-6  # held as firmly as without payload
    tau_diff = env.unwrapped.sim.get_force_torque() - bare.unwrapped.sim.get_force_torque()
    model = FrankaModel()
    g0 = model.gravity(q)
    model.set_payload(1.5, PAYLOAD_COM, np.eye(3) * 0.4 * 1.5 * 0.03**2)
    np.testing.assert_allclose(tau_diff, model.gravity(q) - g0, atol=2e-3)
    # and the inertia seen by the joints grows (the payload is a real mass)
    u = env.unwrapped
    hand = mujoco.mj_name2id(u.world.model, mujoco.mjtObj.mjOBJ_BODY, f"{u.sim.prefix}hand")
    assert u.world.model.body_mass[hand] == pytest.approx(u.config.flange_body().mass + 1.5)
    env.close()
    bare.close()


def test_final_info_shares_nothing_with_the_reset_info():
    """A reflex ends the episode on its first step (full torque): the final info repeats the episode's drawn
    dynamics, as fresh objects (the sharing check of Gymnasium's passive checker, written out here as Gymnasium 1.2
    lacks it), so a user who keeps or edits one info does not change the other."""
    def data_shares_objects(a, b):  # Gymnasium >= 1.3 has this check; 1.2 (with Ray) does not
        if isinstance(a, dict) and isinstance(b, dict):
            return a is b or any(data_shares_objects(a[k], b[k]) for k in a.keys() & b.keys())
        if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
            return np.shares_memory(a, b)
        return isinstance(a, (list, dict, np.ndarray)) and a is b

    # (the robot's old interface: full torque at once, no rate limiter)
    env = gym.make("FrankaTorqueTracking-v0", link_mass_range=(0.9, 1.1), action_scale="physical",
                   limit_rate=False).unwrapped
    _, info0 = env.reset(seed=3)
    _, _, term, _, info1 = env.step(env.action_space.high.copy())
    assert term and info1["failure"] == "joint_velocity_violation"
    np.testing.assert_array_equal(info0["link_mass_scale"], info1["link_mass_scale"])
    assert not data_shares_objects(info0, info1)
    assert not data_shares_objects(env.reset(seed=3)[1], env.reset(seed=3)[1])
