"""IBVS/PBVS scripted policies: contract handling and convergence on the simulated FER."""

import numpy as np
import pytest

from franka_vs_gym.experiments.servo import PX_TOL, R_TOL_DEG, T_TOL, run_servo
from franka_vs_gym.policies import IBVSPolicy, PBVSPolicy


def _obs(**over):
    o = {"q": np.array([0, -0.7, 0, -2.3, 0, 1.6, 0.8]), "features": np.full(8, 0.1),
         "features_desired": np.full(8, 0.1), "feature_depth": np.full(4, 0.2), "tag_pose": np.zeros(6),
         "tag_pose_desired": np.array([0, 0, 0.2, np.pi, 0, 0]), "visible": np.array([1.0])}
    o.update(over)
    return o


@pytest.mark.parametrize("policy", [IBVSPolicy(), PBVSPolicy(), IBVSPolicy(action_type="cartesian_velocity")])
def test_zero_action_when_tag_not_visible(policy):
    a, state = policy.predict(_obs(visible=np.array([0.0])))
    assert state is None
    assert a.dtype == np.float32
    assert a.shape == ((6,) if policy.action_type == "cartesian_velocity" else (7,))
    assert not a.any()


def test_ibvs_at_goal_commands_nothing():
    a, _ = IBVSPolicy().predict(_obs())
    np.testing.assert_allclose(a, 0.0, atol=1e-6)


@pytest.mark.parametrize("bad, match", [({"features": np.full(7, 0.1)}, "shape"),
                                        ({"features": np.full(8, np.nan)}, "NaN"),
                                        ({"visible": None}, "visible")])
def test_bad_observations_are_clear_errors(bad, match):
    o = _obs(**bad)
    if bad.get("visible", 1) is None:
        del o["visible"]
    with pytest.raises(ValueError, match=match):
        IBVSPolicy().predict(o)


def test_actions_respect_joint_velocity_limits():
    far = _obs(features=np.array([0.5, 0.5, 0.9, 0.5, 0.9, 0.9, 0.5, 0.9]), feature_depth=np.full(4, 0.1))
    a, _ = IBVSPolicy(gain=50.0).predict(far)
    from franka_vs_gym.model import params

    assert np.all(np.abs(a) <= np.array(params.DQ_MAX) + 1e-6)


@pytest.mark.parametrize("kind", ["ibvs", "pbvs"])
def test_convergence_from_seeded_starts_ideal_features(kind):
    """Subset of the 100-seed study (scripts/eval_servo.py): every run converges to the stated accuracy."""
    for seed in range(8):
        r = run_servo(kind, seed, features="ideal", duration=8.0)
        assert r.converged, r.summary()
        if kind == "ibvs":
            assert r.final_corner_error_px < PX_TOL
        else:
            assert r.final_translation_error_m < T_TOL and r.final_rotation_error_deg < R_TOL_DEG
        assert r.start_offset_m <= 0.15 and r.start_angle_deg <= 30


def test_ibvs_converges_with_rendering_and_detection_in_the_loop():
    r = run_servo("ibvs", 3, features="detect", duration=8.0)
    assert r.converged, r.summary()
    assert r.final_corner_error_px < PX_TOL
    assert r.detections > 10


def test_pbvs_converges_with_detection_at_640x480():
    from franka_vs_gym.vision import CameraIntrinsics

    r = run_servo("pbvs", 5, features="detect", duration=8.0, intrinsics=CameraIntrinsics.default(640, 480))
    assert r.converged, r.summary()
    assert r.final_translation_error_m < T_TOL and r.final_rotation_error_deg < R_TOL_DEG
