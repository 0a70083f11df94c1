"""FrankaModel: physical properties of B, C, g, friction, kinematics, and agreement with independent evaluations
(our own DH product, a pinocchio model built from the installed URDF, and the MuJoCo plant)."""

import mujoco
import numpy as np
import pinocchio as pin
import pytest
from conftest import random_q

from franka_vs_gym.assets.mjcf import RobotSpec, SceneSpec, mesh_dir, scene_xml
from franka_vs_gym.model import FrankaModel, ModelConfig, RigidBody, Tool, params


@pytest.fixture(scope="module")
def model():
    return FrankaModel()


def test_mass_matrix_symmetric_positive_definite(model, rng):
    for q in random_q(rng, 50):
        B = model.mass_matrix(q)
        np.testing.assert_array_equal(B, B.T)
        assert np.linalg.eigvalsh(B).min() > 1e-4


def test_dB_minus_2C_is_skew_symmetric(model, rng):
    h = 1e-6
    for q in random_q(rng, 20):
        dq = rng.uniform(-2, 2, 7)
        dB = (model.mass_matrix(q + h * dq) - model.mass_matrix(q - h * dq)) / (2 * h)
        N = dB - 2 * model.coriolis_matrix(q, dq)
        np.testing.assert_allclose(N + N.T, 0.0, atol=1e-6)
        np.testing.assert_allclose(model.coriolis_matrix(q, dq) @ dq, model.coriolis(q, dq), atol=1e-9)


def test_gravity_is_gradient_of_potential_energy(model, rng):
    h = 1e-6
    for q in random_q(rng, 20):
        grad = np.array([(model.potential_energy(q + h * e) - model.potential_energy(q - h * e)) / (2 * h)
                         for e in np.eye(7)])
        np.testing.assert_allclose(model.gravity(q), grad, atol=1e-6)


def test_forward_of_inverse_dynamics_is_identity(model, rng):
    cfg = ModelConfig(armature=np.full(7, 0.1), torque_offset=np.arange(7) * 0.1)
    m2 = FrankaModel(cfg)
    for mdl in (model, m2):
        for q in random_q(rng, 20):
            dq, ddq = rng.uniform(-2, 2, 7), rng.uniform(-5, 5, 7)
            tau = mdl.inverse_dynamics(q, dq, ddq)
            np.testing.assert_allclose(mdl.forward_dynamics(q, dq, tau), ddq, atol=1e-8)


def test_inverse_dynamics_is_B_ddq_plus_C_dq_plus_g_plus_friction(model, rng):
    for q in random_q(rng, 10):
        dq, ddq = rng.uniform(-2, 2, 7), rng.uniform(-5, 5, 7)
        expected = (model.mass_matrix(q) @ ddq + model.coriolis_matrix(q, dq) @ dq + model.gravity(q)
                    + model.friction(dq))
        np.testing.assert_allclose(model.inverse_dynamics(q, dq, ddq), expected, atol=1e-9)


def test_friction_is_gaz_sigmoid(model):
    dq = np.linspace(-1, 1, 7)
    p1, p2, p3 = (params.as_array(x) for x in (params.FRICTION_PHI1, params.FRICTION_PHI2, params.FRICTION_PHI3))
    expected = p1 / (1 + np.exp(-p2 * (dq + p3))) - p1 / (1 + np.exp(-p2 * p3))
    np.testing.assert_allclose(model.friction(dq), expected, atol=1e-12)
    # dissipative away from the small offset velocity
    v = np.full(7, 0.5)
    assert (model.friction(v) * v > 0).all()


def _dh_fk(q):
    """Independent forward kinematics: the product of modified-DH transforms, in plain numpy."""
    T = np.eye(4)
    for a, d, alpha, th in zip(params.DH_A, params.DH_D, params.DH_ALPHA, q, strict=True):
        ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(th), np.sin(th)
        T = T @ np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -sa * d], [st * sa, ct * sa, ca, ca * d],
                          [0, 0, 0, 1]])
    T = T @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, params.FLANGE_D], [0, 0, 0, 1]])
    c, s = np.cos(params.HAND_YAW), np.sin(params.HAND_YAW)
    return T @ np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, params.HAND_TCP_Z], [0, 0, 0, 1]])


def test_kinematics_match_independent_dh_evaluation(model, rng):
    for q in random_q(rng, 50):
        np.testing.assert_allclose(model.fMe(q), _dh_fk(q), atol=1e-12)


def test_neutral_pose_end_effector_position(model):
    """Known TCP position of the FER + Hand at the neutral pose: (0.307, 0, 0.487) m, pointing down."""
    M = model.fMe(params.as_array(params.Q_NEUTRAL))
    np.testing.assert_allclose(M[:3, 3], [0.30689, 0.0, 0.48688], atol=1e-4)
    np.testing.assert_allclose(M[:3, 2], [0, 0, -1], atol=1e-9)


def test_jacobians_match_finite_differences(model, rng):
    h = 1e-7
    for q in random_q(rng, 10):
        J = model.fJe(q)
        M0 = model.fMe(q)
        for i in range(7):
            dq = np.zeros(7)
            dq[i] = h
            M1 = model.fMe(q + dq)
            np.testing.assert_allclose((M1[:3, 3] - M0[:3, 3]) / h, J[:3, i], atol=1e-5)
            dR = (M1[:3, :3] @ M0[:3, :3].T - np.eye(3)) / h
            np.testing.assert_allclose([dR[2, 1], dR[0, 2], dR[1, 0]], J[3:, i], atol=1e-5)
        R = M0[:3, :3]
        np.testing.assert_allclose(model.eJe(q), np.block([[R.T, np.zeros((3, 3))], [np.zeros((3, 3)), R.T]]) @ J,
                                   atol=1e-12)


def test_jacobian_derivative(model, rng):
    h = 1e-6
    q = random_q(rng, 1)[0]
    dq = rng.uniform(-1, 1, 7)
    num = (model.fJe(q + h * dq) - model.fJe(q - h * dq)) / (2 * h)
    np.testing.assert_allclose(model.fJe_dot(q, dq), num, atol=1e-6)


def test_inverse_kinematics_roundtrip(model, rng):
    for q in random_q(rng, 5, margin=0.3):
        target = model.fMe(q)
        sol = model.inverse_kinematics(target, q + rng.normal(0, 0.1, 7))
        np.testing.assert_allclose(model.fMe(sol), target, atol=1e-7)
    far = np.eye(4)
    far[:3, 3] = [3.0, 0, 0]
    with pytest.raises(ValueError, match="no in-limit solution"):
        model.inverse_kinematics(far, restarts=2)


def test_matches_pinocchio_model_built_from_urdf(rng):
    """The franka_description URDF (links + hand, fingers locked closed) gives the same B and g once its two 15 g
    fingers, which our lumped hand leaves out, are added as a payload at the finger joint origin."""
    fingers = RigidBody(0.03, [0, 0, params.HAND_FINGER_Z], 2 * np.diag([2.375e-06, 2.375e-06, 7.5e-07]))
    model = FrankaModel(ModelConfig(payload=fingers))
    urdf = str(mesh_dir().parents[1] / "urdf" / "panda.urdf")
    full = pin.buildModelFromUrdf(urdf)
    arm = pin.buildReducedModel(full, [full.getJointId("panda_finger_joint1"),
                                       full.getJointId("panda_finger_joint2")], pin.neutral(full))
    data = arm.createData()
    for q in random_q(rng, 10):
        B = pin.crba(arm, data, q)
        B = np.triu(B) + np.triu(B, 1).T
        np.testing.assert_allclose(model.mass_matrix(q), B, atol=1e-9)
        np.testing.assert_allclose(model.gravity(q), pin.computeGeneralizedGravity(arm, data, q), atol=1e-8)


# ----------------------------------------------------------------------------- agreement with the MuJoCo plant
def _plant(cfg, base_quat=(1, 0, 0, 0)):
    m = mujoco.MjModel.from_xml_string(scene_xml(SceneSpec(robots=[RobotSpec(config=cfg, camera=False,
                                                                                 base_quat=base_quat)],
                                                           table=False)))
    return m, mujoco.MjData(m)


def _compare_with_plant(cfg, rng, n=30, gravity_world=None):
    fm = FrankaModel(cfg)
    m, d = _plant(cfg)
    if gravity_world is not None:
        m.opt.gravity[:] = gravity_world
    M = np.zeros((7, 7))
    for q in random_q(rng, n):
        d.qpos[:] = q
        d.qvel[:] = rng.uniform(-2, 2, 7)
        mujoco.mj_forward(m, d)
        mujoco.mj_fullM(m, d, M)
        np.testing.assert_allclose(fm.mass_matrix(q), M, atol=1e-6)
        np.testing.assert_allclose(fm.bias(q, d.qvel), d.qfrc_bias, atol=1e-6)


def test_model_matches_plant_default(rng):
    _compare_with_plant(ModelConfig(), rng)


def test_model_matches_plant_with_payload_and_armature(rng):
    cfg = ModelConfig(payload=RigidBody(1.5, [0.01, -0.02, 0.08], np.diag([0.004, 0.005, 0.003])),
                      armature=np.array([0.3, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1]))
    _compare_with_plant(cfg, rng)
    fm = FrankaModel()
    fm.set_payload(1.5, [0.01, -0.02, 0.08], [0.004, 0.005, 0.003])
    fm.set_config(fm.config.copy(armature=cfg.armature))
    q = random_q(rng, 1)[0]
    np.testing.assert_allclose(fm.mass_matrix(q), FrankaModel(cfg).mass_matrix(q), atol=1e-12)


def test_model_matches_plant_without_tool(rng):
    _compare_with_plant(ModelConfig(tool=Tool.none()), rng)


def test_model_matches_plant_with_tilted_gravity(rng):
    g = np.array([2.0, -1.5, -9.5])
    _compare_with_plant(ModelConfig(gravity=g), rng)


def test_payload_changes_gravity_by_its_weight(rng):
    """A point payload of mass m at the TCP adds J_v^T (-m g0) to the gravity torques."""
    fm, fp = FrankaModel(), FrankaModel()
    flMe = fm.config.tool.flMe
    fp.set_payload(2.0, flMe[:3, 3])
    for q in random_q(rng, 5):
        Jv = fm.fJe(q)[:3]
        np.testing.assert_allclose(fp.gravity(q) - fm.gravity(q), Jv.T @ (-2.0 * fm.config.gravity), atol=1e-9)


def test_config_file_roundtrip_and_no_overwrite(tmp_path):
    cfg = ModelConfig(payload=RigidBody(0.5, [0, 0, 0.05], [1e-3, 1e-3, 1e-3]), armature=np.full(7, 0.05),
                      torque_offset=np.linspace(-0.2, 0.2, 7), delay=0.002)
    p = cfg.save(tmp_path / "cal.json")
    back = ModelConfig.load(p)
    assert back.to_dict() == cfg.to_dict()
    with pytest.raises(FileExistsError):
        cfg.save(p)
    np.testing.assert_allclose(FrankaModel(p).mass_matrix(np.zeros(7)), FrankaModel(cfg).mass_matrix(np.zeros(7)))


@pytest.mark.parametrize("bad, match", [
    ({"format": "other/9"}, "unsupported model file format"),
    ({"armature": [0.1] * 6}, "armature must have shape"),
    ({"gravity": [0, 0, float("nan")]}, "NaN"),
    ({"payload": {"mass": -1, "com": [0, 0, 0], "inertia": [0, 0, 0]}}, "mass"),
    ({"tool": "gripper9000"}, "unknown tool"),
    ({"frobnicate": 1}, "unknown keys"),
])
def test_config_errors_name_the_problem(bad, match):
    with pytest.raises(ValueError, match=match):
        ModelConfig.from_dict(bad)


def test_model_rejects_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="model file not found"):
        FrankaModel(str(tmp_path / "nope.json"))
