"""Visual-servoing control laws (pure functions of the features and the model).

    v_c = -lambda(||e||_inf) L^+ e

with the interaction matrix L chosen as CURRENT (at s, Z), DESIRED (at s*, Z*) or MEAN (the average of both), and
ViSP's adaptive gain ``lambda(x) = (l0 - linf) exp(-l0' x / (l0 - linf)) + linf``: large (l0) near convergence,
small (linf) far from it, with slope l0' at zero. The camera twist v_c = [v; w] (in c) maps to joint velocities
through ``dq = (cVe eJe)^+ v_c``.

Eye-to-hand (a camera c fixed in the world, the target carried by the end effector e): the features move as
``s_dot = -L cVe eJe dq`` (the target's motion seen from a fixed camera is the opposite of the camera moving with the
same twist), and the law is ViSP's (vpServo, ``EYETOHAND_L_cVe_eJe`` / ``EYETOHAND_L_cVf_fVe_eJe`` /
``EYETOHAND_L_cVf_fJe``): the task Jacobian ``J = -L cVa aJe`` with ``cVa aJe`` = ``cVe eJe``, ``cVf fVe eJe``
or ``cVf fJe``, and ``dq = -lambda J^+ e``. Here cVe = V(cMf fMe) changes as the robot moves; cVf = V(cMf) is the
camera's calibrated placement. The third form is exact only when fJe is the end effector's twist reduced at f's
origin (``fVe eJe``); with the Jacobian of e's origin velocity in base axes (libfranka's zero Jacobian,
FrankaModel.fJe) it leaves out the lever-arm term ``[f_t_e]x w`` (see :func:`spatial_jacobian`).
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


def _points_task(s: np.ndarray, s_star: np.ndarray, Z: np.ndarray, Z_star: np.ndarray,
                 interaction: InteractionMatrixType | str) -> tuple[np.ndarray, np.ndarray]:
    """The point features' interaction matrix L (2n, 6) of the chosen kind and the error e = s - s* (2n,), with the
    inputs checked; shared by the eye-in-hand and eye-to-hand IBVS laws."""
    s, s_star = np.asarray(s, dtype=np.float64), np.asarray(s_star, dtype=np.float64)
    if s.shape != s_star.shape or s.ndim != 1 or len(s) % 2:
        raise ValueError(f"s and s_star must be (2n,) arrays of the same shape, got {s.shape} and {s_star.shape}")
    if not (np.isfinite(s).all() and np.isfinite(s_star).all()):
        raise ValueError("features contain NaN or inf")
    kind = InteractionMatrixType(interaction)
    if kind == InteractionMatrixType.CURRENT:
        L = points_interaction_matrix(s.reshape(-1, 2), Z)
    elif kind == InteractionMatrixType.DESIRED:
        L = points_interaction_matrix(s_star.reshape(-1, 2), Z_star)
    else:
        L = 0.5 * (points_interaction_matrix(s.reshape(-1, 2), Z)
                   + points_interaction_matrix(s_star.reshape(-1, 2), Z_star))
    return L, s - s_star


def ibvs_velocity(s: np.ndarray, s_star: np.ndarray, Z: np.ndarray, Z_star: np.ndarray,
                  interaction: InteractionMatrixType | str = InteractionMatrixType.CURRENT,
                  gain: AdaptiveGain | float = AdaptiveGain()) -> tuple[np.ndarray, np.ndarray]:
    """IBVS with point features: (camera twist v_c (6,), error e (2n,)).

    s, s_star: (2n,) normalized coordinates (x0, y0, x1, y1, ...); Z, Z_star: (n,) depths (m).
    Lost points must be removed by the caller (with at least 3 points left the 6 dof stay controllable).
    """
    L, e = _points_task(s, s_star, Z, Z_star, interaction)
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


# ---------------------------------------------------------------------------------------------------- eye-to-hand
class EyeToHandForm(str, Enum):
    """The eye-to-hand task Jacobians of ViSP's vpServo (the robot's twist mapped into the camera frame)."""

    cVe_eJe = "EYETOHAND_L_cVe_eJe"
    cVf_fVe_eJe = "EYETOHAND_L_cVf_fVe_eJe"
    cVf_fJe = "EYETOHAND_L_cVf_fJe"


def spatial_jacobian(fMe: np.ndarray, eJe: np.ndarray) -> np.ndarray:
    """fVe eJe (6, 7): the end effector's twist reduced at the base origin, in base axes (the fJe that makes
    ``cVf fJe`` equal to ``cVe eJe``)."""
    return twist_transform(np.asarray(fMe, dtype=np.float64)) @ np.asarray(eJe, dtype=np.float64)


def eye_to_hand_task_jacobian(L: np.ndarray, form: EyeToHandForm | str = EyeToHandForm.cVe_eJe, *,
                              cVe: np.ndarray | None = None, eJe: np.ndarray | None = None,
                              cVf: np.ndarray | None = None, fVe: np.ndarray | None = None,
                              fJe: np.ndarray | None = None) -> np.ndarray:
    """J = -L cVa aJe (k, 7) of an eye-to-hand task with interaction matrix L (k, 6): ``s_dot = J dq``.

    ``form`` picks the product as ViSP does: cVe eJe (needs cVe, eJe), cVf fVe eJe (cVf, fVe, eJe) or cVf fJe
    (cVf, fJe)."""
    kind = EyeToHandForm(form)
    need = {EyeToHandForm.cVe_eJe: ("cVe", "eJe"), EyeToHandForm.cVf_fVe_eJe: ("cVf", "fVe", "eJe"),
            EyeToHandForm.cVf_fJe: ("cVf", "fJe")}[kind]
    given = {"cVe": cVe, "eJe": eJe, "cVf": cVf, "fVe": fVe, "fJe": fJe}
    missing = [n for n in need if given[n] is None]
    if missing:
        raise ValueError(f"{kind.value} needs {', '.join(need)}; missing {', '.join(missing)}")
    if kind == EyeToHandForm.cVe_eJe:
        cVa, aJe = np.asarray(cVe, dtype=np.float64), np.asarray(eJe, dtype=np.float64)
    elif kind == EyeToHandForm.cVf_fVe_eJe:
        cVa, aJe = np.asarray(cVf, dtype=np.float64) @ np.asarray(fVe, dtype=np.float64), np.asarray(eJe, float)
    else:
        cVa, aJe = np.asarray(cVf, dtype=np.float64), np.asarray(fJe, dtype=np.float64)
    return -(np.asarray(L, dtype=np.float64) @ cVa @ aJe)


def eye_to_hand_joint_velocity(e: np.ndarray, J: np.ndarray, lam: float, rcond: float = 1e-6) -> np.ndarray:
    """dq = -lambda J^+ e (7,) for the task Jacobian J (k, 7) and error e (k,) (singular values below ``rcond``
    times the largest are dropped, as ViSP's pseudo-inverse threshold)."""
    return -lam * (np.linalg.pinv(J, rcond=rcond) @ np.asarray(e, dtype=np.float64))


def ibvs_eye_to_hand(s: np.ndarray, s_star: np.ndarray, Z: np.ndarray, Z_star: np.ndarray,
                     interaction: InteractionMatrixType | str = InteractionMatrixType.CURRENT,
                     gain: AdaptiveGain | float = AdaptiveGain(), form: EyeToHandForm | str = EyeToHandForm.cVe_eJe,
                     **frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eye-to-hand IBVS with point features: (joint velocities dq (7,), error e (2n,)). s, s_star, Z, Z_star as
    :func:`ibvs_velocity`; ``frames`` the twists and Jacobians of ``form`` (see :func:`eye_to_hand_task_jacobian`)."""
    L, e = _points_task(s, s_star, Z, Z_star, interaction)
    J = eye_to_hand_task_jacobian(L, form, **frames)
    return eye_to_hand_joint_velocity(e, J, _gain(gain)(float(np.abs(e).max()))), e


def pbvs_eye_to_hand(cMo: np.ndarray, cdMo: np.ndarray, gain: AdaptiveGain | float = AdaptiveGain(),
                     form: EyeToHandForm | str = EyeToHandForm.cVe_eJe, **frames: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Eye-to-hand PBVS on (t, theta u) of cdMc = cdMo (cMo)^-1 (the target brought to cdMo in the fixed camera):
    (joint velocities dq (7,), error e (6,))."""
    e, L = pbvs_features(cMo, cdMo)
    J = eye_to_hand_task_jacobian(L, form, **frames)
    return eye_to_hand_joint_velocity(e, J, _gain(gain)(float(np.abs(e).max()))), e
