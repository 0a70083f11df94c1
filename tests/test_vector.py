"""The batched vector env (gymnasium.make_vec on mujoco.batch): bit for bit the trajectories of N single envs."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import franka_vs_gym  # noqa: F401
from franka_vs_gym.envs.vector import FrankaVectorEnv
from franka_vs_gym.sim import plant

pytestmark = pytest.mark.skipif(not plant.NATIVE, reason="the batched vector env needs the compiled plant")


def _same(x, y) -> bool:
    if isinstance(x, dict):
        return set(x) == set(y) and all(_same(x[k], y[k]) for k in x)
    if x is None or y is None:
        return x is y
    if isinstance(x, np.ndarray) and x.dtype == object:
        return x.shape == y.shape and all(_same(u, v) for u, v in zip(x, y, strict=True))
    if isinstance(x, (np.ndarray, np.generic, float, int, bool)):
        return np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)
    return x == y


def _same_info(a: dict, b: dict, where: str) -> None:
    assert set(a) == set(b), where
    for k in a:
        if isinstance(a[k], dict):
            _same_info(a[k], b[k], f"{where}/{k}")
        else:
            assert _same(a[k], b[k]), f"{where}/{k}"


def _same_step(r1: tuple, r2: tuple, t: int) -> None:
    """Two vector steps' (obs, reward, terminated, truncated, info) equal bit for bit."""
    for k in r1[0]:
        assert np.array_equal(r1[0][k], r2[0][k]), (t, k)
    for j in (1, 2, 3):
        assert np.array_equal(r1[j], r2[j]), (t, j)
    _same_info(r1[4], r2[4], f"step {t}")


def _compare_with_single_envs(env_id, kwargs, n_steps, *, n=3, seed=7, torque_scale=5.0, autoreset_mode=None):
    """Step the batched env and Gymnasium's SyncVectorEnv of single envs with the same seeds and actions; every
    observation, reward, flag and info must be equal, bit for bit. Returns (episode ends, failures, robot-steps
    taken in the batch by the task's logic)."""
    vkw = {} if autoreset_mode is None else {"autoreset_mode": autoreset_mode}
    kwargs = {"action_scale": "physical", **kwargs}  # (the actions below are in physical units unless normalized)
    vec = gym.make_vec(env_id, num_envs=n, nthread=2, task_logic=True, **vkw, **kwargs)
    assert isinstance(vec, FrankaVectorEnv)
    ref = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", vector_kwargs=vkw, **kwargs)
    o1, i1 = vec.reset(seed=seed)
    o2, i2 = ref.reset(seed=seed)
    _same_info(i1, i2, "reset")
    rng = np.random.default_rng(0)
    scale = 0.4 if vec.single_action_space.shape == (7,) and vec.envs[0].action_type != "torque" else torque_scale
    if kwargs["action_scale"] != "physical":
        scale = 1.0  # uniformly random over the normalized space
    ends, failures, in_batch = 0, set(), 0
    for t in range(n_steps):
        a = (rng.uniform(-1, 1, vec.action_space.shape) * scale).astype(np.float32)
        r1, r2 = vec.step(a), ref.step(a)
        _same_step(r1, r2, t)
        ends += int((r1[2] | r1[3]).sum())
        failures |= {f for f, m in zip(r1[4].get("failure", []), r1[4].get("_failure", []), strict=False) if m and f}
        in_batch += int(vec._in_batch.sum())
        if t == n_steps // 2:  # the robots' environments hold their current state when read (then step on)
            for e1, e2 in zip(vec.envs, ref.envs, strict=True):
                np.testing.assert_array_equal(e1.unwrapped.sim.q, e2.unwrapped.sim.q)
                assert e1.unwrapped._steps == e2.unwrapped._steps
    vec.close()
    ref.close()
    return ends, failures, in_batch


@pytest.mark.parametrize("env_id, kwargs, n_steps", [
    # randomised dynamics, a camera slower than the control (frames between steps), one autoreset
    ("FrankaIBVS-v0", dict(observation_type="features", link_mass_range=(0.8, 1.2), friction_scale_range=(0.5, 1.5),
                           payload_mass_range=(0.0, 0.5), feature_noise=0.5, control_period=0.04,
                           camera_period=0.03, time_limit=2.0), 60),
    ("FrankaTorqueTracking-v0", dict(friction_scale_range=(0.5, 1.5), time_limit=0.3), 40),
    # the default visual periods (a camera frame at the end of every period, in the batch) with payload randomised
    ("FrankaIBVS-v0", dict(observation_type="features", payload_mass_range=(0.0, 1.0), time_limit=1.0), 30),
    # large random torques: reflexes stop robots (ControlException -> info["failure"]), then autoreset
    ("FrankaTorqueTracking-v0", dict(time_limit=1.0, clip_actions=True, torque_scale=80.0), 40),
])
def test_batched_vector_env_is_bit_identical_to_single_envs(env_id, kwargs, n_steps):
    kwargs = dict(kwargs)
    torque_scale = kwargs.pop("torque_scale", 5.0)
    ends, failures, _ = _compare_with_single_envs(env_id, kwargs, n_steps, torque_scale=torque_scale)
    assert ends >= 3  # every robot's episode ended at least once and was reset (autoreset)
    if torque_scale > 50:
        assert failures, "the large torques should have tripped a reflex"


@pytest.mark.parametrize("env_id, kwargs, n_steps, mode", [
    # every registered id on the task logic over all robots, a few hundred steps across autoresets
    ("FrankaIBVS-v0", dict(link_mass_range=(0.8, 1.2), time_limit=0.6), 200, None),
    ("FrankaIBVS-v0", dict(observation_type="state", payload_mass_range=(0.0, 0.5), time_limit=0.5), 150,
     AutoresetMode.SAME_STEP),
    ("FrankaPBVS-v0", dict(friction_scale_range=(0.5, 1.5), time_limit=0.6), 200, None),
    # observation noise drawn from each robot's generator in a single env's order (pixels, then joints)
    ("FrankaIBVS-v0", dict(feature_noise=0.5, joint_noise=1e-3, velocity_noise=1e-3, time_limit=0.6), 150, None),
    ("FrankaVisualTorque-v0", dict(link_mass_range=(0.9, 1.1), time_limit=0.3, torque_scale=1.0), 300, None),
    ("FrankaTorqueTracking-v0", dict(action_type="joint_velocity", link_mass_range=(0.8, 1.2), joint_noise=1e-3,
                                     velocity_noise=1e-2, time_limit=0.5), 300, None),
    ("FrankaTorqueTracking-v0", dict(friction_scale_range=(0.5, 1.5), time_limit=0.4, clip_actions=True,
                                     torque_scale=1.0), 300,
     AutoresetMode.SAME_STEP),
    # the default interface (normalized actions, rate limiter) and the robot's old one (no limiter)
    ("FrankaTorqueTracking-v0", dict(action_scale="normalized", time_limit=0.5), 300, None),
    ("FrankaVisualTorque-v0", dict(action_scale="normalized", time_limit=0.3), 300, None),
    ("FrankaIBVS-v0", dict(action_scale="normalized", time_limit=0.6), 200, None),
    ("FrankaTorqueTracking-v0", dict(limit_rate=False, time_limit=0.4, torque_scale=1.0), 300, None),
    # the eye-to-hand tasks (the camera's placement drawn per episode, a static observation key), pixel noise
    ("FrankaIBVSEyeToHand-v0", dict(link_mass_range=(0.9, 1.1), time_limit=0.6), 200, None),
    ("FrankaPBVSEyeToHand-v0", dict(friction_scale_range=(0.5, 1.5), time_limit=0.6), 200, AutoresetMode.SAME_STEP),
    ("FrankaIBVSEyeToHand-v0", dict(feature_noise=0.5, joint_noise=1e-3, time_limit=0.6), 200, None),
    # the joint-limit guard at work: random joint velocities for long enough to reach the limits
    ("FrankaTorqueTracking-v0", dict(action_type="joint_velocity", action_scale="normalized", robot="fr3",
                                     max_tracking_error=None, control_period=0.05, time_limit=4.0), 300, None),
])
def test_task_logic_over_all_robots_is_bit_identical_to_single_envs(env_id, kwargs, n_steps, mode):
    """The configurations whose per-step logic runs once for all robots (franka_vs_gym.envs.batched): the same
    trajectories, rewards, flags and infos as single envs, through failures (tag lost, joint limits, reflexes)
    and autoresets, and most robot-steps really taken in the batch."""
    kwargs = dict(kwargs)
    torque_scale = kwargs.pop("torque_scale", 5.0)
    ends, _, in_batch = _compare_with_single_envs(env_id, kwargs, n_steps, torque_scale=torque_scale,
                                                  autoreset_mode=mode)
    assert ends >= 6
    assert in_batch >= 0.6 * 3 * n_steps


def _model_field(m, name):
    return np.asarray(getattr(m.opt, name[4:]) if name.startswith("opt.") else getattr(m, name))


def _batch_runs_each_robots_model(vec) -> None:
    """Every field mujoco.batch can hold per simulation equals, bit for bit, the robot's own model's."""
    from mujoco import batch as mjbatch

    envs = vec._envs
    for i, e in enumerate(envs):
        bm = vec.batch.get_model(i)
        for name in mjbatch.MODEL_FIELDS:
            a, b = _model_field(bm, name), _model_field(e.world.model, name)
            assert a.tobytes() == b.tobytes(), (i, name)


def test_the_batch_holds_one_model_and_each_robots_differing_fields():
    """The batch runs one model (not a copy per robot) and holds per robot only the fields that differ: each robot's
    tag placement and randomised masses and friction (a reset draws them), and an edit made through ``envs``."""
    vec = gym.make_vec("FrankaIBVS-v0", num_envs=4, nthread=1, link_mass_range=(0.8, 1.2),
                       friction_scale_range=(0.5, 1.5), time_limit=0.1)
    vec.reset(seed=3)
    a = np.zeros(vec.action_space.shape, np.float32)
    vec.step(a)
    assert vec.batch.models is None  # no caller models: the batch's own, with per-robot fields
    held = set(vec._batch_models.expanded)
    assert {"body_pos", "body_mass", "body_inertia", "jnt_user"} <= held, held
    assert "geom_size" not in held and "mesh_vert" not in held
    _batch_runs_each_robots_model(vec)
    # the differing fields found from the models' memory as a whole are those a field-by-field comparison finds
    bm, base = vec._batch_models, vec.batch.model
    assert all(b is not None for b in bm._bufs)
    for i, e in enumerate(vec._envs):
        m = e.world.model
        by_field = {n for n in bm._fields if getattr(m, n).tobytes() != getattr(base, n).tobytes()}
        assert bm._differing(i) == by_field, i
        assert bm._differing(i, assets=False) == by_field, i  # (after a reset: the assets are not compared)
        assert {"body_pos", "body_mass"} <= by_field
    for _ in range(15):  # through autoresets (new draws)
        vec.step(a)
    vec.envs[2].unwrapped.sim.set_dynamics(friction_scale=0.25)  # an edit through envs, read before the next step
    vec.step(a)
    _batch_runs_each_robots_model(vec)
    vec.close()
    # without randomisation no robot's masses or friction are held per robot
    vec = gym.make_vec("FrankaTorqueTracking-v0", num_envs=3, nthread=1)
    vec.reset(seed=0)
    vec.step(np.zeros(vec.action_space.shape, np.float32))
    assert not {"body_mass", "jnt_user"} & set(vec._batch_models.expanded)
    _batch_runs_each_robots_model(vec)
    vec.close()

def test_same_step_autoreset_and_partial_reset():
    kw = dict(time_limit=0.05)  # 5 steps of FrankaTorqueTracking-v0
    vec = FrankaVectorEnv("FrankaTorqueTracking-v0", 2, autoreset_mode="SameStep", **kw)
    assert vec.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    single = gym.make("FrankaTorqueTracking-v0", **kw)
    vec.reset(seed=1)
    o, _ = single.reset(seed=1)
    a = np.zeros(vec.action_space.shape, np.float32)
    for _ in range(5):
        obs, r, term, trunc, info = vec.step(a)
        o, *_ = single.step(a[0])
    assert trunc.all() and "final_obs" in info
    assert np.array_equal(info["final_obs"][0]["q"], o["q"])  # the last observation of the episode
    assert obs["time"][0, 0] == 0.0  # and the first of the next one
    obs, _ = vec.reset(seed=[5, None], options={"reset_mask": np.array([True, False])})
    o, _ = single.reset(seed=5)
    assert np.array_equal(obs["q"][0], o["q"])
    with pytest.raises(ValueError, match="num_envs"):
        FrankaVectorEnv("FrankaTorqueTracking-v0", 0)
    with pytest.raises(ValueError, match="unknown environment id"):
        FrankaVectorEnv("Nope-v0", 2)


def test_sb3_vec_env_equals_dummy_vec_env_of_agent_envs():
    """The SB3 adapter over the batched env gives SB3 what DummyVecEnv over the training wrappers gives it."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    from franka_vs_gym.envs.sb3 import make_agent_vec_env
    from franka_vs_gym.envs.wrappers import make_agent_env

    kw = dict(time_limit=0.5, link_mass_range=(0.9, 1.1))
    ours = make_agent_vec_env("FrankaIBVS-v0", 2, 0.5, nthread=1, **kw)
    ref = DummyVecEnv([lambda: make_agent_env("FrankaIBVS-v0", 0.5, **kw) for _ in range(2)])
    ours.seed(11)
    ref.seed(11)
    assert np.array_equal(ours.reset(), ref.reset())
    rng = np.random.default_rng(3)
    dones = 0
    for _ in range(14):
        a = rng.uniform(-1, 1, (2, 7)).astype(np.float32)
        ours.step_async(a)
        ref.step_async(a)
        o1, r1, d1, i1 = ours.step_wait()
        o2, r2, d2, i2 = ref.step_wait()
        assert np.array_equal(o1, o2) and np.array_equal(r1, r2) and np.array_equal(d1, d2)
        for x, y in zip(i1, i2, strict=True):
            assert x["TimeLimit.truncated"] == y["TimeLimit.truncated"]
            if "terminal_observation" in y:
                assert np.array_equal(x["terminal_observation"], y["terminal_observation"])
        dones += int(d1.sum())
    assert dones == 2  # both episodes (10 steps) ended and were reset within the step
    ours.close()


def test_ppo_trains_on_the_batched_env(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, str(root / "baselines" / "train_sb3.py"), "--smoke", "--algo", "ppo",
                        "--batched", "--n-envs", "4", "--out", str(tmp_path / "ppo"), "--tensorboard", "",
                        "--eval-episodes", "0"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "ppo.zip").is_file() and '"batched": true' in (tmp_path / "ppo.json").read_text()


def test_image_observations_equal_single_envs():
    """Image observations: each robot's wrist image rendered from its scene as a single env renders it."""
    kw = dict(observation_type="features+image", time_limit=0.3, link_mass_range=(0.9, 1.1))
    vec = gym.make_vec("FrankaIBVS-v0", num_envs=2, **kw)
    ref = gym.make_vec("FrankaIBVS-v0", num_envs=2, vectorization_mode="sync", **kw)
    o1, _ = vec.reset(seed=4)
    o2, _ = ref.reset(seed=4)
    assert np.array_equal(o1["image"], o2["image"])
    a = np.full(vec.action_space.shape, 0.2, dtype=np.float32)
    for _ in range(7):  # through the end of the 6-step episodes and the autoreset
        r1, r2 = vec.step(a), ref.step(a)
        for k in r1[0]:
            assert np.array_equal(r1[0][k], r2[0][k]), k
        assert np.array_equal(r1[1], r2[1])
    assert o1["image"].std() > 1.0  # a real image
    vec.close()
    ref.close()


@pytest.mark.parametrize("task_logic", [True, False])
def test_batched_env_reports_a_reflex_at_its_crossing_step_as_single_envs(task_logic):
    """Full wrist torque: the velocity reflex fires inside a control period (one batch call); the batched env's robots
    end their episodes at the same step as single envs, with the same reason and detail (the time, joint and value
    of the crossing step, inside the period)."""
    n, env_id = 2, "FrankaTorqueTracking-v0"
    vec = gym.make_vec(env_id, num_envs=n, nthread=2, task_logic=task_logic, action_scale="physical")
    singles = [gym.make(env_id, action_scale="physical") for _ in range(n)]
    vec.reset(seed=3)
    for i, s in enumerate(singles):
        s.reset(seed=3 + i)
    a = np.zeros((n, 7), np.float32)
    a[:, 6] = 12.0
    for _ in range(100):
        _, _, term, _, info = vec.step(a)
        refs = [s.step(a[i]) for i, s in enumerate(singles)]
        assert list(term) == [r[2] for r in refs]
        if term.any():
            break
    assert term.all()
    for i, s in enumerate(singles):
        assert info["failure"][i] == refs[i][4]["failure"] == "joint_velocity_violation"
        assert info["reflex"][i] == refs[i][4]["reflex"] and "joint 6" in info["reflex"][i]
        t = float(info["reflex"][i].split()[0][2:])  # "t=0.1230 s: joint 6 at ..."
        u = s.unwrapped
        assert u.world.time - u.n_substeps * u.physics_step < t < u.world.time - 0.5 * u.physics_step  # mid-period
        np.testing.assert_array_equal(vec.envs[i].sim.q, u.sim.q)  # held at the same position
    vec.close()
    for s in singles:
        s.close()


def test_a_robot_diverging_in_the_batch_reports_it_as_a_single_env():
    """One robot's integrator sabotaged (5 s steps): its batch step blows up, the robot is put back at the state
    before the step and its environment re-runs it alone, so it reports "diverged: ..." as a single env does (and
    the other robots, still in the batch, are unaffected), through the autoresets that follow."""
    n, env_id = 4, "FrankaTorqueTracking-v0"
    vec = gym.make_vec(env_id, num_envs=n, nthread=2, task_logic=True, time_limit=0.3, action_scale="physical")
    ref = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", time_limit=0.3, action_scale="physical")
    for v in (vec, ref):
        m = v.envs[1].unwrapped.world.model
        m.opt.timestep = 5.0
        m.dof_armature[:] = 0.0
    vec.reset(seed=2)
    ref.reset(seed=2)
    a = np.zeros((n, 7), np.float32)
    a[1] = np.array([87, -87, 87, -87, 12, -12, 12]) * 0.2
    diverged = others_in_batch = 0
    for t in range(40):
        r1, r2 = vec.step(a), ref.step(a)
        _same_step(r1, r2, t)
        f = r1[4].get("failure", [None] * n)
        diverged += sum(1 for x, m in zip(f, r1[4].get("_failure", []), strict=False) if m and x and
                        x.startswith("diverged"))
        others_in_batch += int(vec._in_batch[[0, 2, 3]].all())
    assert diverged >= 10
    assert others_in_batch >= 35  # the other robots stepped in the batch (but at their first step and autoreset)
    vec.close()
    ref.close()


@pytest.mark.parametrize("env_id, task_logic", [("FrankaTorqueTracking-v0", False), ("FrankaTorqueTracking-v0", True),
                                                ("FrankaIBVSEyeToHand-v0", None)])
def test_contacts_equal_single_envs_without_persistent_data(env_id, task_logic):
    """Without a camera image the batch keeps one MjData per thread, not per robot, so a robot that ends a period
    in contact (the table raised into its hand) runs that period again alone, as a single env: the same contacts,
    failures and observations as single envs, bit for bit."""
    kw = dict(action_scale="physical", time_limit=0.5)
    if env_id != "FrankaTorqueTracking-v0":
        kw["observation_type"] = "features"
    n = 4
    vec = gym.make_vec(env_id, num_envs=n, nthread=1, task_logic=task_logic, **kw)
    ref = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", **kw)
    assert not vec._persistent
    vec.reset(seed=3)
    ref.reset(seed=3)
    # robot 0's table raised until it just touches the arm at the start pose (0.5 mm deep: contacts, no reflex)
    u = ref.envs[0].unwrapped
    m, d = u.world.model, mujoco.MjData(u.world.model)
    mujoco.mj_copyData(d, m, u.world.data)
    table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
    z0 = m.geom_pos[table, 2]
    for z in np.arange(z0, z0 + 1.0, 0.0005):
        m.geom_pos[table, 2] = z
        mujoco.mj_forward(m, d)
        if d.ncon:
            break
    assert d.ncon
    vec.envs[0].unwrapped.world.model.geom_pos[table, 2] = z
    rng = np.random.default_rng(1)
    touching = 0
    for t in range(40):
        a = (rng.uniform(-1, 1, vec.action_space.shape) * 0.2).astype(np.float32)
        r1, r2 = vec.step(a), ref.step(a)
        _same_step(r1, r2, t)
        touching += sum(int(e.unwrapped.world.data.ncon > 0) for e in ref.envs)
    assert touching >= 5, touching
    vec.close()
    ref.close()
