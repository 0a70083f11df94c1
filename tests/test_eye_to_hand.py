"""The eye-to-hand camera: ViSP's eye-to-hand laws to machine precision, the task Jacobian against the kinematics
(finite differences), the scene against MuJoCo's own placement of the camera and tag, the policies on both robots,
the vector env against single envs, and clear errors."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pinocchio as pin
import pytest

import franka_vs_gym  # noqa: F401  (registers the ids)
from franka_vs_gym.control.visual_servo import (
    AdaptiveGain,
    EyeToHandForm,
    eye_to_hand_task_jacobian,
    ibvs_eye_to_hand,
    pbvs_eye_to_hand,
    spatial_jacobian,
)
from franka_vs_gym.envs.eye_to_hand import DEFAULT_eMo
from franka_vs_gym.model import FrankaModel
from franka_vs_gym.model.geometry import CAMERA_VISP_TO_MUJOCO, homogeneous, inverse_pose
from franka_vs_gym.policies import IBVSEyeToHandPolicy, PBVSEyeToHandPolicy
from franka_vs_gym.vision.features import pbvs_features, points_interaction_matrix
from franka_vs_gym.vision.tags import tag_corners

IDS = ["FrankaIBVSEyeToHand-v0", "FrankaPBVSEyeToHand-v0"]
FORMS = [f.value for f in EyeToHandForm]


def _V(aMb):
    """ViSP's vpVelocityTwistMatrix of aMb, written out: [[R, [t]x R], [0, R]]."""
    R, t = aMb[:3, :3], aMb[:3, 3]
    V = np.zeros((6, 6))
    V[:3, :3] = V[3:, 3:] = R
    V[:3, 3:] = pin.skew(t) @ R
    return V


def _scene(rng):
    """A random arm posture, a fixed camera 0.4 m in front of the tag carried by the hand, the tag's corners."""
    model = FrankaModel()
    q = model.robot.neutral() + rng.uniform(-0.3, 0.3, 7)
    fMo = model.fMe(q) @ DEFAULT_eMo
    cMo_goal = homogeneous(pin.exp3(rng.uniform(-0.2, 0.2, 3)) @ np.diag([1.0, -1.0, -1.0]),
                           (*rng.uniform(-0.03, 0.03, 2), 0.4))
    cMf = cMo_goal @ inverse_pose(fMo)
    return model, q, cMf


def _features(model, q, cMf, corners):
    cMo = cMf @ model.fMe(q) @ DEFAULT_eMo
    P = corners @ cMo[:3, :3].T + cMo[:3, 3]
    return (P[:, :2] / P[:, 2:]).ravel(), P[:, 2], cMo


def _visp_qdot(L, cVa, aJe, e, lam):
    """vpServo::computeControlLaw for an eye-to-hand type: J1 = -L cVa aJe, J1p its pseudo-inverse (threshold 1e-6),
    e1 = WpW J1p e with WpW the projector on J1's row space when J1 is rank deficient, qdot = -lambda e1."""
    J1 = -1.0 * (L @ cVa @ aJe)
    U, sv, Vt = np.linalg.svd(J1)
    rank = int((sv > 1e-6 * sv[0]).sum())
    J1p = np.linalg.pinv(J1, rcond=1e-6)
    e1 = J1p @ e
    if rank < J1.shape[1]:
        imJ1t = Vt[:rank].T
        e1 = imJ1t @ imJ1t.T @ e1
    return -lam * e1


@pytest.mark.parametrize("form", FORMS)
def test_ibvs_eye_to_hand_is_visp_law_to_machine_precision(rng, form):
    corners = tag_corners(0.08)
    for _ in range(10):
        model, q, cMf = _scene(rng)
        s, Z, _ = _features(model, q, cMf, corners)
        s_star = s + rng.normal(0.0, 0.02, 8)
        Z_star = Z + rng.normal(0.0, 0.02, 4)
        fMe, eJe = model.fMe(q), model.eJe(q)
        frames = {EyeToHandForm.cVe_eJe.value: {"cVe": _V(cMf @ fMe), "eJe": eJe},
                  EyeToHandForm.cVf_fVe_eJe.value: {"cVf": _V(cMf), "fVe": _V(fMe), "eJe": eJe},
                  EyeToHandForm.cVf_fJe.value: {"cVf": _V(cMf), "fJe": _V(fMe) @ eJe}}[form]
        gain = AdaptiveGain(4.0, 0.4, 30.0)
        dq, e = ibvs_eye_to_hand(s, s_star, Z, Z_star, "MEAN", gain, form, **frames)
        L = 0.5 * (points_interaction_matrix(s.reshape(4, 2), Z) + points_interaction_matrix(s_star.reshape(4, 2),
                                                                                              Z_star))
        cVa, aJe = (_V(cMf @ fMe), eJe) if form != EyeToHandForm.cVf_fJe.value else (_V(cMf), _V(fMe) @ eJe)
        lam = (4.0 - 0.4) * np.exp(-30.0 * np.abs(s - s_star).max() / 3.6) + 0.4
        ref = _visp_qdot(L, cVa, aJe, s - s_star, lam)
        np.testing.assert_allclose(dq, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))
        # ViSP's sign convention: the same law as +lambda (L cVe eJe)^+ e (vpServo's documented form)
        np.testing.assert_allclose(dq, lam * np.linalg.pinv(L @ cVa @ aJe, rcond=1e-6) @ (s - s_star),
                                   atol=1e-12 * max(1.0, np.abs(ref).max()))


def test_pbvs_eye_to_hand_is_visp_law_to_machine_precision(rng):
    for _ in range(10):
        model, q, cMf = _scene(rng)
        _, _, cMo = _features(model, q, cMf, tag_corners(0.08))
        cdMo = homogeneous(np.diag([1.0, -1.0, -1.0]), (0.0, 0.0, 0.35))
        fMe, eJe = model.fMe(q), model.eJe(q)
        dq, e = pbvs_eye_to_hand(cMo, cdMo, 0.7, "EYETOHAND_L_cVf_fVe_eJe", cVf=_V(cMf), fVe=_V(fMe), eJe=eJe)
        e_ref, L = pbvs_features(cMo, cdMo)
        np.testing.assert_array_equal(e, e_ref)
        ref = _visp_qdot(L, _V(cMf) @ _V(fMe), eJe, e_ref, 0.7)
        np.testing.assert_allclose(dq, ref, rtol=0, atol=1e-12 * max(1.0, np.abs(ref).max()))


def test_task_jacobian_predicts_the_feature_motion(rng):
    """s_dot = -L cVe eJe dq against finite differences of the features through the kinematics: the physics the
    laws rest on. ViSP's cVf fJe form needs fJe reduced at the base origin (fVe eJe); with the Jacobian of e's origin
    velocity (libfranka's zero Jacobian, FrankaModel.fJe) it misses the lever-arm term, by a lot."""
    corners = tag_corners(0.08)
    h = 1e-7
    for _ in range(10):
        model, q, cMf = _scene(rng)
        s, Z, _ = _features(model, q, cMf, corners)
        L = points_interaction_matrix(s.reshape(4, 2), Z)
        dq = rng.normal(0.0, 0.3, 7)
        s2, _, _ = _features(model, pin.integrate(model.model, q, dq * h), cMf, corners)
        fd = (s2 - s) / h
        fMe, eJe = model.fMe(q), model.eJe(q)
        for form, frames in ((EyeToHandForm.cVe_eJe, {"cVe": _V(cMf @ fMe), "eJe": eJe}),
                             (EyeToHandForm.cVf_fVe_eJe, {"cVf": _V(cMf), "fVe": _V(fMe), "eJe": eJe}),
                             (EyeToHandForm.cVf_fJe, {"cVf": _V(cMf), "fJe": spatial_jacobian(fMe, eJe)})):
            J = eye_to_hand_task_jacobian(L, form, **frames)
            np.testing.assert_allclose(J @ dq, fd, atol=2e-5 * max(1.0, np.abs(fd).max()))
        zero_jacobian = eye_to_hand_task_jacobian(L, EyeToHandForm.cVf_fJe, cVf=_V(cMf), fJe=model.fJe(q))
        assert np.abs(zero_jacobian @ dq - fd).max() > 0.05 * np.abs(fd).max()


def test_task_jacobian_names_what_it_lacks():
    with pytest.raises(ValueError, match="needs cVf, fVe, eJe; missing fVe"):
        eye_to_hand_task_jacobian(np.zeros((8, 6)), "EYETOHAND_L_cVf_fVe_eJe", cVf=np.eye(6), eJe=np.zeros((6, 7)))
    with pytest.raises(ValueError):
        eye_to_hand_task_jacobian(np.zeros((8, 6)), "EYEINHAND_L_cVe_eJe")


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_scene_matches_mujoco_placement(robot):
    """The task's cMo (pinocchio kinematics, the camera's fMc) equals MuJoCo's own placement of the fixed camera and
    of the tag body on the hand, along a motion."""
    env = gym.make("FrankaIBVSEyeToHand-v0", robot=robot)
    u = env.unwrapped
    # before any reset: the scene's own camera (CameraSpec.from_visp) at the nominal placement, as the task has it
    d = mujoco.MjData(u._m)
    mujoco.mj_fwdPosition(u._m, d)
    wMc = homogeneous(d.cam_xmat[u._cam_id].reshape(3, 3) @ CAMERA_VISP_TO_MUJOCO, d.cam_xpos[u._cam_id])
    np.testing.assert_allclose(wMc, u.sim.get_wMf() @ u.fMc, atol=1e-9)
    env.reset(seed=3)
    for _ in range(5):
        env.step(env.action_space.sample() * 0.1)
        # MuJoCo's kinematics of the state now (mj_step leaves those of the state before its last integration)
        d = mujoco.MjData(u._m)
        d.qpos[:] = u._d.qpos
        mujoco.mj_fwdPosition(u._m, d)
        c, b = u._cam_id, u._tag_body
        wMc = homogeneous(d.cam_xmat[c].reshape(3, 3) @ CAMERA_VISP_TO_MUJOCO, d.cam_xpos[c])
        wMo = homogeneous(d.xmat[b].reshape(3, 3), d.xpos[b])
        np.testing.assert_allclose(inverse_pose(wMc) @ wMo, u.get_cMo(), atol=1e-9)
    env.close()


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_compiled_truth_matches_pinocchio(robot):
    """The compiled eye-to-hand truth (franka_vs_gym/sim/_task.c, the hand's chain carrying the tag) equals the
    record of cMo = cMf fMe(q) eMo from pinocchio's kinematics and the numpy projection, along random motions."""
    from franka_vs_gym.envs.kernels import REC, pose_records
    from franka_vs_gym.sim import plant

    if plant.tag_truth is None:
        pytest.skip("the compiled plant is not built")
    env = gym.make(IDS[0], robot=robot)
    u = env.unwrapped
    worst = 0.0
    for seed in range(2):
        env.reset(seed=seed)
        for _ in range(10):
            env.step(env.action_space.sample())
            assert u._plan.geo_or_none is not None and u._plan.geo[122] == 1.0
            q = u.sim.q
            ref = np.zeros((1, REC))
            pose_records((u.cMf @ u.sim.model.fMe(q) @ u.eMo)[None], ref, tag_size=u.tag_size,
                         intrinsics=u.intrinsics, features_desired=u.features_desired)
            worst = max(worst, float(np.abs(u._truth_now() - ref[0]).max()))
    assert worst < 1e-9, worst
    env.close()


@pytest.mark.parametrize("robot", ["fer", "fr3"])
@pytest.mark.parametrize("env_id, policy", [(IDS[0], IBVSEyeToHandPolicy), (IDS[1], PBVSEyeToHandPolicy)])
def test_policies_converge_on_both_robots(env_id, policy, robot):
    from franka_vs_gym.envs import evaluate

    r = evaluate(policy(robot=robot), env_id, n_episodes=4, seed=10, env_kwargs={"robot": robot})
    assert r["success_rate"] == 1.0, r
    assert r["mean_time_to_converge"] < 3.0


def test_ibvs_converges_with_detection_on_the_rendered_image():
    env = gym.make(IDS[0], feature_source="detection")
    policy = IBVSEyeToHandPolicy()
    obs, _ = env.reset(seed=2)
    for _ in range(env.unwrapped.max_steps):
        obs, _, term, trunc, info = env.step(policy.predict(obs)[0])
        if term or trunc:
            break
    assert info["is_success"], info
    env.close()


def test_vector_env_matches_single_envs():
    """gymnasium.make_vec (the batched env: physics on mujoco.batch, the eye-to-hand task robot by robot) gives the
    single environments' trajectories bit for bit."""
    vec = gym.make_vec(IDS[0], num_envs=3, nthread=2)
    ref = gym.make_vec(IDS[0], num_envs=3, vectorization_mode="sync")
    o1, _ = vec.reset(seed=5)
    o2, _ = ref.reset(seed=5)
    rng = np.random.default_rng(0)
    for t in range(30):
        for k in o1:
            assert np.array_equal(o1[k], o2[k]), (t, k)
        a = (rng.uniform(-1, 1, vec.action_space.shape) * 0.5).astype(np.float32)
        o1, r1, te1, tr1, _ = vec.step(a)
        o2, r2, te2, tr2, _ = ref.step(a)
        assert np.array_equal(r1, r2) and np.array_equal(te1, te2) and np.array_equal(tr1, tr2), t
    vec.close()
    ref.close()


def test_clear_errors():
    with pytest.raises(ValueError, match="tag_x_range.*carried by the hand"):
        gym.make(IDS[0], tag_x_range=(0.4, 0.5))
    with pytest.raises(ValueError, match="action_type"):
        gym.make(IDS[0], action_type="cartesian_velocity")
    env = gym.make("FrankaIBVS-v0")
    obs, _ = env.reset(seed=0)
    with pytest.raises(ValueError, match="camera_pose"):
        IBVSEyeToHandPolicy().predict(obs)
    env.close()


def test_camera_spec_from_visp_places_the_mujoco_camera(rng):
    """A CameraSpec made from a ViSP pose wMc (z forward, y down) renders from that pose: MuJoCo's camera frame
    (looking along -z, y up) is wMc turned half a turn about x."""
    from franka_vs_gym.assets.mjcf import CameraSpec, SceneSpec, scene_xml

    wMc = homogeneous(pin.exp3(rng.uniform(-2, 2, 3)), rng.uniform(-1, 1, 3))
    m = mujoco.MjModel.from_xml_string(scene_xml(SceneSpec(cameras=[CameraSpec.from_visp("fixed", wMc, 45.0)])))
    d = mujoco.MjData(m)
    mujoco.mj_fwdPosition(m, d)
    c = m.camera("fixed").id
    np.testing.assert_allclose(d.cam_xpos[c], wMc[:3, 3], atol=1e-9)
    np.testing.assert_allclose(d.cam_xmat[c].reshape(3, 3), wMc[:3, :3] @ np.diag([1.0, -1.0, -1.0]), atol=1e-9)
    assert m.cam_fovy[c] == 45.0
