"""Visual features, interaction matrices and control laws against independent computations."""

import numpy as np
import pinocchio as pin
import pytest

from franka_vs_gym.control.visual_servo import AdaptiveGain, camera_to_joint_velocity, ibvs_velocity, pbvs_velocity
from franka_vs_gym.model import FrankaModel
from franka_vs_gym.sim.robot import DEFAULT_eMc, twist_transform
from franka_vs_gym.vision.features import (
    pbvs_features,
    point_interaction_matrix,
    points_interaction_matrix,
    thetau_interaction_matrix,
)


def _move(cMo, v, h):
    """Tag pose after the camera moves with twist v (in c) during h."""
    return np.linalg.inv(pin.exp6(pin.Motion(v * h)).homogeneous) @ cMo


def test_point_interaction_matrix_matches_finite_differences(rng):
    h = 1e-7
    for _ in range(20):
        P = np.array([*rng.uniform(-0.2, 0.2, 2), rng.uniform(0.2, 1.0)])
        v = rng.normal(size=6)
        L = point_interaction_matrix(P[0] / P[2], P[1] / P[2], P[2])
        M = np.eye(4)
        M[:3, 3] = P
        P2 = _move(M, v, h)[:3, 3]
        np.testing.assert_allclose((P2[:2] / P2[2] - P[:2] / P[2]) / h, L @ v, atol=1e-5)


def test_hand_derived_interaction_matrix_at_the_optical_axis():
    """At x = y = 0, Z = 0.5: pure depth scaling, rotations about x/y move the point by -/+1."""
    L = point_interaction_matrix(0.0, 0.0, 0.5)
    np.testing.assert_array_equal(L, [[-2, 0, 0, 0, -1, 0], [0, -2, 0, 1, 0, 0]])


def test_pbvs_interaction_matrix_matches_finite_differences(rng):
    h = 1e-7
    for _ in range(10):
        cMo = np.eye(4)
        cMo[:3, :3] = pin.exp3(rng.uniform(-1.2, 1.2, 3))
        cMo[:3, 3] = rng.uniform(-0.1, 0.1, 3) + [0, 0, 0.4]
        cdMo = np.eye(4)
        cdMo[:3, :3] = np.diag([1.0, -1.0, -1.0])
        cdMo[2, 3] = 0.2
        v = rng.normal(size=6)
        e, L = pbvs_features(cMo, cdMo)
        e2, _ = pbvs_features(_move(cMo, v, h), cdMo)
        np.testing.assert_allclose((e2 - e) / h, L @ v, atol=1e-5)
    np.testing.assert_array_equal(thetau_interaction_matrix(np.zeros(3)), np.eye(3))


def test_degenerate_depth_and_lost_points():
    with pytest.raises(ValueError, match="depth Z must be > 0"):
        point_interaction_matrix(0.1, 0.1, 0.0)
    with pytest.raises(ValueError, match="depth Z must be > 0"):
        point_interaction_matrix(0.1, 0.1, -0.3)
    with pytest.raises(ValueError, match="no points"):
        points_interaction_matrix(np.zeros((0, 2)), np.zeros(0))
    with pytest.raises(ValueError, match="NaN"):
        ibvs_velocity(np.full(8, np.nan), np.zeros(8), np.ones(4), np.ones(4))
    # three points are enough for a full-rank 6x6 problem: the law still runs
    s = np.array([0.1, 0.1, -0.1, 0.1, -0.1, -0.1])
    v, e = ibvs_velocity(s * 1.1, s, np.full(3, 0.3), np.full(3, 0.3))
    assert np.isfinite(v).all()
    assert np.linalg.matrix_rank(points_interaction_matrix(s.reshape(3, 2), np.full(3, 0.3))) == 6


def test_adaptive_gain_shape():
    g = AdaptiveGain(4.0, 0.4, 30.0)
    assert g(0.0) == pytest.approx(4.0)
    assert g(1e3) == pytest.approx(0.4)
    h = 1e-7
    assert (g(h) - g(0.0)) / h == pytest.approx(-30.0, rel=1e-4)
    assert AdaptiveGain.constant(0.5)(123.0) == 0.5
    with pytest.raises(ValueError):
        AdaptiveGain(0.4, 4.0, 30.0)


@pytest.mark.parametrize("kind", ["CURRENT", "DESIRED", "MEAN"])
def test_ibvs_decreases_the_error_exponentially_near_the_goal(kind):
    """Near the goal, e_dot = L v = -lambda e: the features converge at the gain's rate (exactly with the CURRENT
    matrix, to first order in the distance to the goal with DESIRED and MEAN)."""
    cdMo = np.eye(4)
    cdMo[:3, :3] = np.diag([1.0, -1.0, -1.0])
    cdMo[2, 3] = 0.2
    corners = np.array([[-0.04, 0.04, 0], [0.04, 0.04, 0], [0.04, -0.04, 0], [-0.04, -0.04, 0]])

    def feats(cMo):
        P = corners @ cMo[:3, :3].T + cMo[:3, 3]
        return (P[:, :2] / P[:, 2:]).ravel(), P[:, 2]

    s_star, Z_star = feats(cdMo)
    cMo = _move(cdMo, np.array([0.01, -0.005, 0.01, 0.02, -0.01, 0.03]), 1.0 if kind == "CURRENT" else 0.05)
    s, Z = feats(cMo)
    v, e = ibvs_velocity(s, s_star, Z, Z_star, kind, 0.5)
    h = 1e-6
    s2, _ = feats(_move(cMo, v, h))
    np.testing.assert_allclose((s2 - s) / h, -0.5 * e, atol=0.02 * np.abs(e).max())


def test_pbvs_is_exponential_and_straight():
    cdMo = np.eye(4)
    cdMo[:3, :3] = np.diag([1.0, -1.0, -1.0])
    cdMo[2, 3] = 0.2
    cMo = _move(cdMo, np.array([0.05, -0.03, 0.08, 0.3, -0.2, 0.4]), 1.0)
    e0, _ = pbvs_features(cMo, cdMo)
    for _ in range(200):
        v, _ = pbvs_velocity(cMo, cdMo, 1.0)
        cMo = _move(cMo, v, 0.01)
    e, _ = pbvs_features(cMo, cdMo)
    np.testing.assert_allclose(e, e0 * np.exp(-2.0), rtol=0.02, atol=1e-6)


def test_camera_twist_maps_to_joint_velocity(rng):
    model = FrankaModel()
    q = np.array([0.1, -0.5, 0.2, -2.0, 0.1, 1.6, 0.7])
    v_c = rng.normal(size=6) * 0.1
    dq = camera_to_joint_velocity(v_c, model.eJe(q), DEFAULT_eMc)
    cVe = twist_transform(np.linalg.inv(DEFAULT_eMc))
    np.testing.assert_allclose(cVe @ model.eJe(q) @ dq, v_c, atol=1e-10)
