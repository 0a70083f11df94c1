"""The environments' per-step formulas over a leading robot axis: one numpy call per quantity for N robots.

A single environment (``gymnasium.make``) calls them with N = 1 (or with its (7,) vectors, where the formula
broadcasts), the batched vector env (:mod:`franka_vs_gym.envs.vector`) with its N robots: each formula has one home,
so both give the same numbers, bit for bit (``tests/test_vector.py``). Shapes: ``(N, ...)``, SI units (rad, rad/s,
Nm, m, s); poses are 4x4 homogeneous matrices ``aMb`` (frame b expressed in frame a).
"""

from __future__ import annotations

import math

import numpy as np
from pinocchio import log3

_sum = np.add.reduce  # (the ufunc's reduction called directly: these run at every step, also with N = 1)


def row_norm(x: np.ndarray) -> np.ndarray:
    """Euclidean norm over the last axis: (..., k) -> (...). (A 1-D vector gives a float64 scalar.)"""
    return np.sqrt(_sum(x * x, axis=-1))


def row_sumsq(x: np.ndarray) -> np.ndarray:
    """Sum of squares over the last axis: (..., k) -> (...)."""
    return _sum(x * x, axis=-1)


def clip_observation(v: np.ndarray, low: np.ndarray, high: np.ndarray, out: np.ndarray | None = None
                     ) -> np.ndarray:
    """The packed observation (..., size) float64, clipped in place to [low, high] (size,), NaN replaced by 0 (a
    NaN never reaches an agent), as float32: a new array, or written into ``out`` (float32, v's shape) and
    returned (the same rounding either way)."""
    np.maximum(v, low, out=v)
    np.minimum(v, high, out=v)
    total = v.sum()
    if total != total:
        v[np.isnan(v)] = 0.0
    if out is None:
        return v.astype(np.float32)
    np.copyto(out, v, casting="same_kind")
    return out


def tracking_desired(q0: np.ndarray, A: np.ndarray, w: np.ndarray, t: np.ndarray | float
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """FrankaTorqueTracking-v0's desired trajectory q_d = q0 + A (1 - cos(w t)) and its first two derivatives:
    q0, A (rad), w (rad/s) (..., 7), t (s) broadcast against them ((N, 1) for N robots, or a float)."""
    wt = w * t
    c, s = np.cos(wt), np.sin(wt)
    Aw = A * w  # (A * w * s is (A * w) * s: the products are evaluated once, in the same order)
    return q0 + A * (1.0 - c), Aw * s, Aw * w * c


def inverse_poses(aMb: np.ndarray) -> np.ndarray:
    """bMa (N, 4, 4) of rigid poses aMb (N, 4, 4): [R^T, -R^T t]."""
    Rt = aMb[:, :3, :3].swapaxes(1, 2)
    out = np.empty_like(aMb)
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.matmul(Rt, aMb[:, :3, 3:4])[:, :, 0]
    out[:, 3] = _LAST_ROW
    return out


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])


def camera_tag_poses(fMe: np.ndarray, eMc: np.ndarray, fMo: np.ndarray) -> np.ndarray:
    """cMo (N, 4, 4) = (fMe eMc)^-1 fMo: the tag o seen from the camera c, from the end-effector poses fMe
    (N, 4, 4) in the robot base frame f, the camera mount eMc (4, 4) and the tag poses fMo (N, 4, 4)."""
    return np.matmul(inverse_poses(np.matmul(fMe, eMc)), fMo)


def pose_vectors(M: np.ndarray) -> np.ndarray:
    """(N, 6) pose vectors (t, theta u) of poses M (N, 4, 4), as :func:`franka_vs_gym.model.geometry.pose_vector`
    (the rotation's logarithm is pinocchio's ``log3``, one call per pose)."""
    out = np.empty((len(M), 6))
    out[:, :3] = M[:, :3, 3]
    for j, m in enumerate(M):
        out[j, 3:] = log3(m[:3, :3])
    return out


def pbvs_errors(cdMo: np.ndarray, cMo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """FrankaPBVS-v0's pose error of the camera: (||t|| (N,) m, ||theta u|| (N,) rad) of cdMc = cdMo (cMo)^-1 =
    [R, t] with R = cdRo cRo^T and t = cdto - R cto, from the goal cdMo (4, 4) and the true tag poses cMo
    (N, 4, 4); theta u is the rotation's logarithm (pinocchio's, as in
    :func:`franka_vs_gym.model.geometry.pose_vector`)."""
    R = np.matmul(cdMo[:3, :3], cMo[:, :3, :3].swapaxes(1, 2))
    tw = np.empty((len(R), 2, 3))  # t and theta u of each robot, both norms in one call
    np.subtract(cdMo[:3, 3], np.matmul(R, cMo[:, :3, 3:4])[:, :, 0], out=tw[:, 0])
    for j, r in enumerate(R):
        tw[j, 1] = log3(r)
    e = row_norm(tw)
    return e[:, 0], e[:, 1]


# ---------------------------------------------------------------------------------------------------- rewards
TAG_LOST = "tag lost: a corner left the image"  # the failure reason of the visual tasks when the tag leaves the view

# Each takes a single robot's Python floats (the single environments: plain float arithmetic, the cheapest on the
# per-step path) or (N,) arrays (the batched env) and computes the same IEEE operations either way (min and sqrt
# are exact in both), so a reward has one home and both paths give the same bits.

def feature_error(features: np.ndarray, visible: np.ndarray | bool, features_desired: np.ndarray):
    """FrankaIBVS-v0's task error ||s - s*|| of the true corners (float, or (N,) from features (N, 8) and visible
    (N,) bool), ||s*|| + 1 where the tag is not seen."""
    if not isinstance(visible, np.ndarray):
        return float(row_norm(features - features_desired)) if visible else float(row_norm(features_desired)) + 1.0
    return np.where(visible, row_norm(features - features_desired), row_norm(features_desired) + 1.0)


def feature_reward(err, error_scale: float):
    """FrankaIBVS-v0's per-step reward -min(sqrt(err / error_scale), 1) of the feature error err (float or (N,))."""
    if isinstance(err, float):
        return -min(math.sqrt(err / error_scale), 1.0)
    return -np.minimum(np.sqrt(err / error_scale), 1.0)


def pose_reward(et, er, translation_scale: float, rotation_scale: float):
    """FrankaPBVS-v0's per-step reward -min(et / translation_scale + er / rotation_scale, 1) of the camera's
    translation error et (m) and rotation error er (rad) (floats or (N,))."""
    if isinstance(et, float):
        return -min(et / translation_scale + er / rotation_scale, 1.0)
    return -np.minimum(et / translation_scale + er / rotation_scale, 1.0)


def tracking_reward(err, error_scale: float):
    """FrankaTorqueTracking-v0's per-step reward -min(err / error_scale, 1) of the tracking error err (rad, float
    or (N,))."""
    if isinstance(err, float):
        return -min(err / error_scale, 1.0)
    return -np.minimum(err / error_scale, 1.0)


def success_bonus(reward, success, bonus: float):
    """reward + bonus where success (floats and bool, or (N,) arrays)."""
    if isinstance(reward, float):
        return reward + (bonus if success else 0.0)
    return reward + np.where(success, bonus, 0.0)


def torque_penalty(tau: np.ndarray, tau_max: np.ndarray, cost: float):
    """FrankaVisualTorque-v0's torque cost: cost * mean((tau / tau_max)^2) of the commanded torques tau (7,) or
    (N, 7), Nm (a float, or (N,))."""
    return cost * row_sumsq(tau / tau_max) / 7.0


__all__ = ["TAG_LOST", "camera_tag_poses", "clip_observation", "feature_error", "feature_reward", "inverse_poses",
           "pbvs_errors", "pose_reward", "pose_vectors", "row_norm", "row_sumsq", "success_bonus", "torque_penalty",
           "tracking_desired", "tracking_reward"]
