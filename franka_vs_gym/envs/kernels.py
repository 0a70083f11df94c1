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

from franka_vs_gym.sim import plant

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


def tracking_rows(q0: np.ndarray, A: np.ndarray, w: np.ndarray, t: np.ndarray, q: np.ndarray, desired: np.ndarray,
                  err: np.ndarray) -> None:
    """FrankaTorqueTracking-v0's desired trajectory and tracking error of n robots, written into ``desired``
    (n, 21: q_d, dq_d, ddq_d) and ``err`` (n,): q0, A, w, q (n, 7) (or (7,) for one robot) and t (n,) float64, C
    order. The compiled kernel when built (the formula's one home then, which the single env and the batched vector
    env both call), else :func:`tracking_desired` and :func:`row_norm` (the same formulas in numpy)."""
    if plant.tracking is not None:
        plant.tracking(q0, A, w, t, q, desired, err)
        return
    qd, dqd, ddqd = tracking_desired(q0, A, w, np.asarray(t).reshape(-1, 1))
    d = desired.reshape(-1, 21)
    d[:, :7], d[:, 7:14], d[:, 14:] = qd, dqd, ddqd
    err[:] = row_norm(np.reshape(q, (-1, 7)) - d[:, :7])


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
    (N, 7), Nm (a float, or (N,)). The squares are summed joint after joint (the compiled kernel's order, which the
    single environment's fast step uses too)."""
    tau = np.ascontiguousarray(tau, dtype=np.float64)
    if plant.torque_cost is not None:
        out = np.empty(tau.shape[:-1] or (1,))
        plant.torque_cost(tau, np.ascontiguousarray(tau_max, dtype=np.float64), float(cost), out)
        return float(out[0]) if tau.ndim == 1 else out
    x = tau / tau_max
    ss = x[..., 0] * x[..., 0]
    for k in range(1, 7):
        ss = ss + x[..., k] * x[..., k]
    out = cost * ss / 7.0
    return float(out) if tau.ndim == 1 else out


# ---------------------------------------------------------------------------------------------------- truth records
# The visual tasks' ground truth of the tag at a robot state, one record of REC numbers (the layout of the compiled
# kernel, franka_vs_gym/sim/_task.c): features (x, y of the 4 corners, normalized; zeros when the tag is behind the
# camera or not facing it), corner depths Z (m), visible (1/0), cMo (4 x 4, row-major), the pose vector of cMo
# (t, theta u) and the feature error ||s - s*|| (||s*|| + 1 when not visible).
REC = 36
R_FEATURES, R_DEPTH, R_VISIBLE, R_CMO, R_POSE, R_ERROR = slice(0, 8), slice(8, 12), 12, slice(13, 29), slice(29, 35), 35
GEO = 123  # numbers of a geometry block (the chain, the tag's corners, the camera, the desired features, the setup)


def camera_geometry(model, eMc: np.ndarray, corners: np.ndarray, intrinsics, features_desired: np.ndarray,
                    eye_to_hand: bool = False) -> np.ndarray | None:
    """The geometry block (GEO,) of the compiled truth kernel for a robot's kinematic model (a FrankaModel: its
    seven joint placements and the end effector e, then the camera mount eMc), the tag's corners (4, 3) in the tag
    frame, the camera's intrinsics and the desired features (8,); None when the chain is not seven revolute joints
    about their z axes with e on the last (the truth is then computed with the model itself).

    ``eye_to_hand=True``: the hand carries the tag, ``eMc`` is then the tag's pose eMo in e, and the static pose
    the kernel is given with each q is the fixed camera's cMf (cMo = cMf fMe(q) eMo) instead of the tag's fMo."""
    pm = model.model
    if pm.nq != 7 or pm.njoints != 8 or any(pm.joints[j].shortname() != "JointModelRZ" for j in range(1, 8)):
        return None
    frame = pm.frames[model._e_id]
    if frame.parentJoint != 7:
        return None
    geo = np.zeros(GEO)
    for k in range(7):
        P = pm.jointPlacements[k + 1]
        geo[12 * k:12 * k + 9] = P.rotation.ravel()
        geo[12 * k + 9:12 * k + 12] = P.translation
    tail = frame.placement.homogeneous @ eMc
    geo[84:93] = tail[:3, :3].ravel()
    geo[93:96] = tail[:3, 3]
    geo[96:108] = np.asarray(corners, dtype=np.float64).ravel()
    f, c, hi = intrinsics.pixel_arrays
    geo[108:114] = (f[0], f[1], c[0], c[1], hi[0], hi[1])
    geo[114:122] = features_desired
    geo[122] = 1.0 if eye_to_hand else 0.0
    return geo


def truth_records(geo: np.ndarray | None, q: np.ndarray, fMo: np.ndarray, out: np.ndarray, *, fMe=None, eMc=None,
                  tag_size: float = 0.0, intrinsics=None, features_desired=None) -> np.ndarray:
    """The truth records (N, REC) written into ``out`` for joint positions q (N, 7) and tag poses fMo (N, 4, 4)
    in the robot base frame: the compiled kernel with the geometry block ``geo`` when it exists, else (no compiled
    extension, or a chain it does not cover) the same quantities from the end-effector poses ``fMe`` (N, 4, 4) and
    the camera mount, tag size, intrinsics and desired features given (numpy and pinocchio, the same formulas).
    (An eye-to-hand geometry block, see :func:`camera_geometry`, takes the camera's cMf in place of fMo.)"""
    if geo is not None and plant.tag_truth is not None:
        plant.tag_truth(geo, q, fMo, out)
        return out
    cMo = camera_tag_poses(np.asarray(fMe), eMc, np.asarray(fMo).reshape(-1, 4, 4))
    return pose_records(cMo, out, tag_size=tag_size, intrinsics=intrinsics, features_desired=features_desired)


def pose_records(cMo: np.ndarray, out: np.ndarray, *, tag_size: float, intrinsics, features_desired: np.ndarray
                 ) -> np.ndarray:
    """The truth records (N, REC) written into ``out`` for tag poses cMo (N, 4, 4) in the camera frame (numpy and
    pinocchio; any camera placement, e.g. a camera fixed in the world seeing a tag on the hand)."""
    from franka_vs_gym.vision.tags import project_tag

    _, xy, Z, vis = project_tag(cMo, tag_size, intrinsics)
    n = len(cMo)
    out[:, R_FEATURES] = xy.reshape(n, 8)
    out[:, R_DEPTH] = Z
    out[:, R_VISIBLE] = vis
    out[:, R_CMO] = cMo.reshape(n, 16)
    out[:, R_POSE] = pose_vectors(cMo)
    out[:, R_ERROR] = feature_error(xy.reshape(n, 8), vis, features_desired)
    return out


__all__ = ["GEO", "REC", "R_CMO", "R_DEPTH", "R_ERROR", "R_FEATURES", "R_POSE", "R_VISIBLE", "TAG_LOST",
           "camera_geometry", "camera_tag_poses", "clip_observation", "feature_error", "feature_reward",
           "inverse_poses", "pbvs_errors", "pose_records", "pose_reward", "pose_vectors", "row_norm", "row_sumsq",
           "success_bonus", "torque_penalty", "tracking_desired", "tracking_reward", "tracking_rows",
           "truth_records"]
