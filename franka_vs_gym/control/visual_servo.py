"""Visual-servoing control laws (pure functions of the features and the model).

    v_c = -lambda(||e||_inf) L^+ e

with the interaction matrix L chosen as CURRENT (at s, Z), DESIRED (at s*, Z*) or MEAN (the average of both), and
ViSP's adaptive gain ``lambda(x) = (l0 - linf) exp(-l0' x / (l0 - linf)) + linf``: large (l0) near convergence,
small (linf) far from it, with slope l0' at zero. The camera twist v_c = [v; w] (in c) maps to joint velocities
through ``dq = (cVe eJe)^+ v_c``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum

import numpy as np

from franka_vs_gym.model.geometry import twist_transform
from franka_vs_gym.vision.features import pbvs_features, points_interaction_matrix


class InteractionMatrixType(str, Enum):
    CURRENT = "CURRENT"
    DESIRED = "DESIRED"
    MEAN = "MEAN"


@dataclass(frozen=True)
class AdaptiveGain:
    """ViSP's adaptive gain: ``gain_zero`` (l0) at x = 0, ``gain_inf`` (linf) as x -> inf, ``slope_zero`` (l0') the
    slope at 0. A constant gain is AdaptiveGain(l, l, 0)."""

    gain_zero: float = 4.0
    gain_inf: float = 0.4
    slope_zero: float = 30.0

    def __post_init__(self) -> None:
        if not (self.gain_zero > 0 and self.gain_inf > 0 and self.slope_zero >= 0):
            raise ValueError("adaptive gain needs gain_zero > 0, gain_inf > 0, slope_zero >= 0")
        if self.gain_inf > self.gain_zero:
            raise ValueError("adaptive gain needs gain_inf <= gain_zero")

    @classmethod
    def constant(cls, gain: float) -> AdaptiveGain:
        return cls(gain, gain, 0.0)

    def __call__(self, x: float) -> float:
        a = self.gain_zero - self.gain_inf
        if a == 0:
            return self.gain_zero
        return a * math.exp(-self.slope_zero * x / a) + self.gain_inf


def _gain(gain: AdaptiveGain | float) -> AdaptiveGain:
    return gain if isinstance(gain, AdaptiveGain) else AdaptiveGain.constant(float(gain))


def ibvs_velocity(s: np.ndarray, s_star: np.ndarray, Z: np.ndarray, Z_star: np.ndarray,
                  interaction: InteractionMatrixType | str = InteractionMatrixType.CURRENT,
                  gain: AdaptiveGain | float = AdaptiveGain()) -> tuple[np.ndarray, np.ndarray]:
    """IBVS with point features: (camera twist v_c (6,), error e (2n,)).

    s, s_star: (2n,) normalized coordinates (x0, y0, x1, y1, ...); Z, Z_star: (n,) depths (m).
    Lost points must be removed by the caller (with at least 3 points left the 6 dof stay controllable).
    """
    s, s_star = np.asarray(s, dtype=np.float64), np.asarray(s_star, dtype=np.float64)
    if s.shape != s_star.shape or s.ndim != 1 or len(s) % 2:
        raise ValueError(f"s and s_star must be (2n,) arrays of the same shape, got {s.shape} and {s_star.shape}")
    if not (np.isfinite(s).all() and np.isfinite(s_star).all()):
        raise ValueError("features contain NaN or inf")
    kind = InteractionMatrixType(interaction)
    e = s - s_star
    if kind == InteractionMatrixType.CURRENT:
        L = points_interaction_matrix(s.reshape(-1, 2), Z)
    elif kind == InteractionMatrixType.DESIRED:
        L = points_interaction_matrix(s_star.reshape(-1, 2), Z_star)
    else:
        L = 0.5 * (points_interaction_matrix(s.reshape(-1, 2), Z)
                   + points_interaction_matrix(s_star.reshape(-1, 2), Z_star))
    lam = _gain(gain)(float(np.abs(e).max()))
    return -lam * np.linalg.pinv(L) @ e, e


def pbvs_velocity(cMo: np.ndarray, cdMo: np.ndarray,
                  gain: AdaptiveGain | float = AdaptiveGain()) -> tuple[np.ndarray, np.ndarray]:
    """PBVS on (t, theta u) of cdMc: (camera twist v_c (6,), error e (6,)). The camera translation and rotation
    converge along straight lines (in cd for the translation)."""
    e, L = pbvs_features(cMo, cdMo)
    lam = _gain(gain)(float(np.abs(e).max()))
    return -lam * np.linalg.solve(L, e), e


def camera_to_joint_velocity(v_c: np.ndarray, eJe: np.ndarray, eMc: np.ndarray, rcond: float = 1e-4) -> np.ndarray:
    """Joint velocities (7,) realising the camera twist v_c (6,): dq = (cVe eJe)^+ v_c."""
    cVe = twist_transform(np.linalg.inv(eMc))
    return np.linalg.pinv(cVe @ eJe, rcond=rcond) @ np.asarray(v_c, dtype=np.float64)
