"""Input checks shared by the model, the simulator and the controllers: bad input gets a ValueError naming it."""

from __future__ import annotations

from typing import Any

import numpy as np


def as_vector(x: Any, n: int, name: str) -> np.ndarray:
    """``x`` as a finite float64 array of shape (n,); ValueError naming ``name`` otherwise."""
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array of shape ({n},), got {type(x).__name__}") from None
    if a.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains NaN or inf: {a}")
    return a


def as_pose(M: Any, name: str) -> np.ndarray:
    """``M`` as a finite 4x4 homogeneous matrix whose rotation part is a rotation; ValueError otherwise."""
    try:
        a = np.asarray(M, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a finite 4x4 homogeneous matrix, got {type(M).__name__}") from None
    if a.shape != (4, 4) or not np.isfinite(a).all():
        raise ValueError(f"{name} must be a finite 4x4 homogeneous matrix, got shape {a.shape}")
    R = a[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise ValueError(f"{name}: the rotation part is not a rotation matrix")
    return a
