"""Rigid-body geometry helpers shared by the model, the simulator and the control laws (ViSP conventions).

Poses are 4x4 homogeneous matrices ``aMb`` (frame b expressed in a); twists are [v; w] (6,).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

# ViSP's camera frame (z forward, x right, y down) and MuJoCo's (looking along -z, y up) differ by a half turn about
# x: R_mujoco = R_visp @ CAMERA_VISP_TO_MUJOCO and back (the matrix is its own inverse).
CAMERA_VISP_TO_MUJOCO = np.diag([1.0, -1.0, -1.0])

_EYE4 = np.eye(4)  # copied where a pose is built (a copy costs a fifth of np.eye(4); these run every env step)
_EYE4.flags.writeable = False


def homogeneous(R: np.ndarray, t: np.ndarray | tuple | list) -> np.ndarray:
    """4x4 pose from a rotation matrix (3, 3) and a translation (3,)."""
    M = _EYE4.copy()
    M[:3, :3] = R
    M[:3, 3] = t
    return M


def twist_transform(aMb: np.ndarray) -> np.ndarray:
    """6x6 velocity twist matrix aVb mapping a twist [v; w] expressed in b to one expressed in a (ViSP's
    vpVelocityTwistMatrix)."""
    R, t = aMb[:3, :3], aMb[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    V = np.zeros((6, 6))
    V[:3, :3] = R
    V[:3, 3:] = tx @ R
    V[3:, 3:] = R
    return V


def pose_vector(M: np.ndarray) -> np.ndarray:
    """(tx, ty, tz, thetaux, thetauy, thetauz) of a 4x4 pose, as vpPoseVector."""
    return np.concatenate([M[:3, 3], pin.log3(M[:3, :3])])


def inverse_pose(aMb: np.ndarray) -> np.ndarray:
    """bMa (4, 4) of a rigid pose aMb."""
    R, t = aMb[:3, :3], aMb[:3, 3]
    out = _EYE4.copy()
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def pose_from_vector(p: np.ndarray) -> np.ndarray:
    """4x4 pose from a pose vector (tx, ty, tz, thetaux, thetauy, thetauz), as vpHomogeneousMatrix(vpPoseVector)."""
    M = _EYE4.copy()
    M[:3, :3] = pin.exp3(np.asarray(p[3:], dtype=np.float64))
    M[:3, 3] = p[:3]
    return M


def parallel_axis(mass: float, r: np.ndarray) -> np.ndarray:
    """Parallel-axis (Steiner) term (3, 3), kg m^2: ``mass (|r|^2 I - r r^T)``, the inertia of a point mass at r.

    The inertia of a body about a point p is its inertia about its centre of mass c plus ``parallel_axis(m, c - p)``.
    """
    r = np.asarray(r, dtype=np.float64)
    return mass * ((r @ r) * np.eye(3) - np.outer(r, r))


def rotate_inertia(R: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """An inertia tensor (3, 3) expressed in frame b, re-expressed in frame a: ``R I R^T`` with R = aRb."""
    return R @ inertia @ R.T


def combine_inertials(bodies) -> tuple[float, np.ndarray, np.ndarray]:
    """Lump rigid bodies ``(mass kg, com (3,) m, inertia (3, 3) about the com, kg m^2)`` given in one frame into one:
    (total mass, combined com (3,), inertia (3, 3) about the combined com). An empty or massless set gives zeros."""
    bodies = [(float(m), np.asarray(c, dtype=np.float64), np.asarray(i, dtype=np.float64)) for m, c, i in bodies]
    total = sum(m for m, _, _ in bodies)
    if total == 0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = np.sum([m * c for m, c, _ in bodies], axis=0) / total
    inertia = np.zeros((3, 3))
    for m, c, i in bodies:
        inertia += i + parallel_axis(m, c - com)
    return total, com, inertia


def rot_x(a: float) -> np.ndarray:
    """Rotation (3, 3) by ``a`` rad about x."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    """Rotation (3, 3) by ``a`` rad about y."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    """Rotation (3, 3) by ``a`` rad about z."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def desired_tag_pose(distance: float) -> np.ndarray:
    """The visual-servoing goal cdMo (4, 4): the tag centred, ``distance`` m in front of the camera, facing it (tag z
    towards the camera, tag x along the camera x), as in ViSP's Franka visual-servoing examples. The rotation is
    exactly diag(1, -1, -1) (a half turn about x)."""
    return homogeneous(np.diag([1.0, -1.0, -1.0]), (0.0, 0.0, distance))
