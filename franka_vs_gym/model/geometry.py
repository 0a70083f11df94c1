"""Rigid-body geometry helpers shared by the model, the simulator and the control laws (ViSP conventions).

Poses are 4x4 homogeneous matrices ``aMb`` (frame b expressed in a); twists are [v; w] (6,).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin


def homogeneous(R: np.ndarray, t: np.ndarray | tuple | list) -> np.ndarray:
    """4x4 pose from a rotation matrix (3, 3) and a translation (3,)."""
    M = np.eye(4)
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
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def pose_from_vector(p: np.ndarray) -> np.ndarray:
    """4x4 pose from a pose vector (tx, ty, tz, thetaux, thetauy, thetauz), as vpHomogeneousMatrix(vpPoseVector)."""
    M = np.eye(4)
    M[:3, :3] = pin.exp3(np.asarray(p[3:], dtype=np.float64))
    M[:3, 3] = p[:3]
    return M
