"""Visual features and their interaction matrices (camera frame c, twists [v; w] of the camera in c).

- Image points in normalized coordinates (x, y) with depth Z: ``L = [[-1/Z, 0, x/Z, x y, -(1 + x^2), y],
  [0, -1/Z, y/Z, 1 + y^2, -x y, -x]]`` (2x6), so that d(x, y)/dt = L v_c for a static point.
- Pose features for PBVS (ViSP's choice with the current-to-desired displacement cdMc): s = (t, theta u) of
  cdMc, s* = 0, with ``L = [[cdRc, 0], [0, L_thetau]]`` and
  ``L_thetau = I + theta/2 [u]x + (1 - sinc(theta) / sinc^2(theta/2)) [u]x^2`` (theta u of cdRc).
"""

from __future__ import annotations

import numpy as np


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def point_interaction_matrix(x: float, y: float, Z: float) -> np.ndarray:
    """2x6 interaction matrix of an image point at normalized (x, y) and depth Z (m) > 0."""
    if not (Z > 0 and np.isfinite(Z)):
        raise ValueError(f"depth Z must be > 0 m (a point in front of the camera), got {Z}")
    iz = 1.0 / Z
    return np.array([[-iz, 0.0, x * iz, x * y, -(1.0 + x * x), y],
                     [0.0, -iz, y * iz, 1.0 + y * y, -x * y, -x]])


def points_interaction_matrix(xy: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """(2n)x6 interaction matrix of n points: xy (n, 2) normalized coordinates, Z (n,) depths in m."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    Z = np.asarray(Z, dtype=np.float64).reshape(-1)
    if len(Z) != len(xy):
        raise ValueError(f"{len(xy)} points but {len(Z)} depths")
    if len(xy) == 0:
        raise ValueError("no points: the interaction matrix is empty (all features lost)")
    return np.vstack([point_interaction_matrix(x, y, z) for (x, y), z in zip(xy, Z, strict=True)])


def theta_u(R: np.ndarray) -> np.ndarray:
    """The axis-angle vector theta u (3,) of a rotation matrix, theta in [0, pi]."""
    import pinocchio as pin

    return np.asarray(pin.log3(np.asarray(R, dtype=np.float64)))


def thetau_interaction_matrix(tu: np.ndarray) -> np.ndarray:
    """3x3 L_thetau of theta u (3,) of cdRc: d(theta u)/dt = L_thetau w_c (w_c the camera angular velocity in c)."""
    tu = np.asarray(tu, dtype=np.float64)
    theta = float(np.linalg.norm(tu))
    if theta < 1e-12:
        return np.eye(3)
    u = tu / theta
    ux = _skew(u)
    sinc = np.sinc(theta / np.pi)  # sin(theta)/theta
    sinc2 = np.sinc(theta / 2 / np.pi)
    return np.eye(3) + theta / 2 * ux + (1 - sinc / sinc2**2) * ux @ ux


def pbvs_features(cMo: np.ndarray, cdMo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PBVS error e = (t, theta u) of cdMc (6,) and its interaction matrix (6, 6)."""
    cdMc = np.asarray(cdMo) @ np.linalg.inv(np.asarray(cMo))
    R, t = cdMc[:3, :3], cdMc[:3, 3]
    tu = theta_u(R)
    L = np.zeros((6, 6))
    L[:3, :3] = R
    L[3:, 3:] = thetau_interaction_matrix(tu)
    return np.concatenate([t, tu]), L
