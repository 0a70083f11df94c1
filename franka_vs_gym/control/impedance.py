"""Impedance controllers and gravity compensation for the FER in torque control.

Every controller returns a *gravity-free* joint torque command (7,), Nm, as libfranka expects (the robot adds the
gravity torque g(q) of the model it was told about: arm, tool and declared load). Each uses the model library
(:class:`~franka_vs_gym.model.FrankaModel`: B, C, g, friction, Jacobians) and costs a few tens of microseconds per
call, so it runs at the FER's 1 kHz.

- :class:`GravityCompensation`: hold nothing, compensate only the gravity the robot does not know about (an object
  the controller's model holds but the robot's internal model does not), plus optional joint damping.
- :class:`JointImpedance`: a joint spring-damper ``K (q_d - q) + D (dq_d - dq)`` with Coriolis compensation and
  optional inertial feed-forward.
- :class:`CartesianImpedance`: a spring-damper on the end-effector pose in the base frame f, mapped with ``J^T``,
  with damping (and optional stiffness) acting only in the dynamically consistent null space of the task.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from franka_vs_gym.model.checks import as_pose, as_vector
from franka_vs_gym.model.franka_model import FrankaModel


def _gains(x: Any, n: int, name: str) -> np.ndarray:
    """Non-negative finite gains broadcast to (n,)."""
    try:
        a = np.broadcast_to(np.asarray(x, dtype=np.float64), (n,)).copy()
    except ValueError:
        raise ValueError(f"{name} must be a scalar or have shape ({n},), got {np.shape(x)}") from None
    if not np.isfinite(a).all() or (a < 0).any():
        raise ValueError(f"{name} must be finite and >= 0, got {a}")
    return a


def _check_model(model: Any, name: str = "model") -> FrankaModel:
    if not isinstance(model, FrankaModel):
        raise ValueError(f"{name} must be a FrankaModel, got {type(model).__name__}")
    return model


def pose_error(fMe: np.ndarray, fMe_d: np.ndarray) -> np.ndarray:
    """Pose error (6,) of the end effector w.r.t. its goal, both 4x4 poses in the base frame f.

    ``[p_d - p; theta u]`` where ``theta u`` is the rotation vector of ``R_d R^T`` expressed in f (rad): the
    angular velocity direction (in f) that turns e towards the goal. Units m and rad.
    """
    R, Rd = fMe[:3, :3], fMe_d[:3, :3]
    Re = Rd @ R.T
    # rotation vector of Re (robust near 0 and pi)
    c = np.clip((np.trace(Re) - 1.0) / 2.0, -1.0, 1.0)
    theta = float(np.arccos(c))
    w = np.array([Re[2, 1] - Re[1, 2], Re[0, 2] - Re[2, 0], Re[1, 0] - Re[0, 1]])
    if theta < 1e-6:
        rot = 0.5 * w
    elif np.pi - theta < 1e-4:
        # near pi: axis from the symmetric part
        B = (Re + np.eye(3)) / 2.0
        axis = np.sqrt(np.clip(np.diag(B), 0.0, None))
        k = int(np.argmax(axis))
        axis = B[:, k] / max(axis[k], 1e-12)
        axis /= np.linalg.norm(axis)
        if axis @ w < 0:
            axis = -axis
        rot = theta * axis
    else:
        rot = theta / (2.0 * np.sin(theta)) * w
    return np.concatenate([fMe_d[:3, 3] - fMe[:3, 3], rot])


def null_space_projector(model: FrankaModel, q: np.ndarray, J: np.ndarray | None = None,
                         B: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Dynamically consistent null-space projector of the end-effector task.

    Returns ``(N, Lambda)``: ``N = I - Jbar J`` (7, 7) with ``Jbar = B^-1 J^T Lambda`` and the task-space inertia
    ``Lambda = (J B^-1 J^T)^-1`` (6, 6). A joint torque ``N^T tau0`` produces no end-effector acceleration.
    """
    J = model.fJe(q) if J is None else J
    B = model.mass_matrix(q) if B is None else B
    Binv_JT = np.linalg.solve(B, J.T)
    Lam = np.linalg.pinv(J @ Binv_JT, rcond=1e-6)
    Jbar = Binv_JT @ Lam
    return np.eye(7) - Jbar @ J, Lam


class GravityCompensation:
    """Gravity compensation only: the arm floats, holding its tool and payload.

    The robot already adds the gravity of what it knows (``internal``: arm, tool, declared load, as libfranka's
    model), so the gravity-free command is ``tau = g_model(q) - g_internal(q) - kd dq [+ F(dq)]``: it compensates
    only the gravity of what the controller's ``model`` holds beyond that (an undeclared object), with optional
    joint damping ``kd`` and friction compensation.

    Parameters
    ----------
    model : FrankaModel
        What the arm really carries, as far as the controller knows.
    internal : FrankaModel or None
        The robot's own model (e.g. ``FrankaSim.model``); None means the same as ``model`` (the command is then
        only damping and friction).
    kd : float or (7,)
        Joint damping, Nm s/rad (default 0).
    friction : bool
        Add the model friction at the measured velocity (makes the arm easier to move by hand).

    Call ``ctrl(q, dq) -> tau`` with q (7,) rad, dq (7,) rad/s; returns (7,) Nm, gravity-free.
    """

    def __init__(self, model: FrankaModel, internal: FrankaModel | None = None, kd: Any = 0.0,
                 friction: bool = False) -> None:
        self.model = _check_model(model)
        self.internal = None if internal is None else _check_model(internal, "internal")
        self.kd = _gains(kd, 7, "kd")
        self.friction = bool(friction)

    def reset(self) -> None:
        """Stateless; present so every controller can be reset the same way."""

    def __call__(self, q: Any, dq: Any) -> np.ndarray:
        q, dq = as_vector(q, 7, "q"), as_vector(dq, 7, "dq")
        tau = -self.kd * dq
        if self.internal is not None:
            tau = tau + self.model.gravity(q) - self.internal.gravity(q)
        if self.friction:
            tau = tau + self.model.friction(dq)
        return tau


class JointImpedance:
    """Joint impedance: ``tau = K (q_d - q) + D (dq_d - dq) + B(q) ddq_d + C(q, dq) dq [+ F(dq_d)]``.

    At rest under an external joint torque ``tau_ext`` the arm settles at ``q = q_d + K^-1 tau_ext``: the static
    joint stiffness is exactly K (the robot compensates gravity, Coriolis vanishes at rest).

    Parameters
    ----------
    model : FrankaModel
    k : float or (7,)
        Joint stiffness, Nm/rad (default 600 on joints 1-4, 250, 150, 50 on joints 5-7).
    d : float, (7,) or None
        Joint damping, Nm s/rad. None: ``2 zeta sqrt(k_i B_ii(q))`` at each call (critical for zeta = 1 on the
        diagonal of the inertia).
    zeta : float
        Damping ratio used when d is None.
    coriolis : bool
        Compensate C(q, dq) dq.
    friction : bool
        Feed-forward the model friction at the desired velocity.
    natural_frequency : float or None
        omega, rad/s. When given, k and d follow the inertia: ``k_i = omega^2 B_ii(q)``, ``d_i = 2 zeta omega
        B_ii(q)`` at each call (k and d arguments are then not used): every joint gets the same bandwidth, which
        keeps the light wrist joints stable under a slower (e.g. 100 Hz) zero-order hold. The static stiffness is
        then ``omega^2 B_ii(q)``, configuration-dependent.

    Call ``ctrl(q, dq, q_d, dq_d=None, ddq_d=None) -> tau`` (all (7,), rad, rad/s, rad/s^2); returns (7,) Nm.
    """

    DEFAULT_K = (600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0)

    def __init__(self, model: FrankaModel, k: Any = DEFAULT_K, d: Any = None, zeta: float = 1.0,
                 coriolis: bool = True, friction: bool = False, natural_frequency: float | None = None) -> None:
        self.model = _check_model(model)
        if natural_frequency is not None and not (natural_frequency > 0 and np.isfinite(natural_frequency)):
            raise ValueError(f"natural_frequency must be a finite number > 0 rad/s, got {natural_frequency}")
        self.natural_frequency = None if natural_frequency is None else float(natural_frequency)
        self.k = _gains(k, 7, "k")
        self.d = None if d is None else _gains(d, 7, "d")
        if not (np.isfinite(zeta) and zeta >= 0):
            raise ValueError(f"zeta must be finite and >= 0, got {zeta}")
        self.zeta = float(zeta)
        self.coriolis = bool(coriolis)
        self.friction = bool(friction)

    def reset(self) -> None:
        """Stateless; present so every controller can be reset the same way."""

    def stiffness(self, q: np.ndarray) -> np.ndarray:
        """The joint stiffness (7,) used at q, Nm/rad."""
        if self.natural_frequency is None:
            return self.k
        return self.natural_frequency**2 * np.diag(self.model.mass_matrix(q))

    def damping(self, q: np.ndarray) -> np.ndarray:
        """The joint damping (7,) used at q, Nm s/rad."""
        if self.natural_frequency is not None:
            return 2.0 * self.zeta * self.natural_frequency * np.diag(self.model.mass_matrix(q))
        if self.d is not None:
            return self.d
        return 2.0 * self.zeta * np.sqrt(self.k * np.diag(self.model.mass_matrix(q)))

    def __call__(self, q: Any, dq: Any, q_d: Any, dq_d: Any = None, ddq_d: Any = None) -> np.ndarray:
        q, dq, q_d = as_vector(q, 7, "q"), as_vector(dq, 7, "dq"), as_vector(q_d, 7, "q_d")
        dq_d = np.zeros(7) if dq_d is None else as_vector(dq_d, 7, "dq_d")
        m = self.model
        tau = self.stiffness(q) * (q_d - q) + self.damping(q) * (dq_d - dq)
        if ddq_d is not None:
            tau += m.mass_matrix(q) @ as_vector(ddq_d, 7, "ddq_d")
        if self.coriolis:
            tau += m.coriolis(q, dq)
        if self.friction:
            tau += m.friction(dq_d)
        return tau


class CartesianImpedance:
    """Cartesian impedance of the end effector with null-space damping (operational-space form).

        F   = K_x e + D_x (v_d - v)                         (6,) wrench at e, base-frame axes
        tau = J^T F + N^T (k_n (q_n - q) - d_n dq) + C(q, dq) dq

    with e = :func:`pose_error` (m, rad), v = fJe dq the end-effector twist [v; w] in f, J = fJe (6, 7) and
    ``N = I - B^-1 J^T Lambda J`` the dynamically consistent null-space projector, so the null-space terms never
    disturb the end effector. At rest under an external wrench W at e, the pose settles at ``e = -K_x^-1 W``.

    Parameters
    ----------
    model : FrankaModel
    k_translation : float or (3,)
        Translational stiffness, N/m (default 500).
    k_rotation : float or (3,)
        Rotational stiffness, Nm/rad (default 30).
    d : (6,) or None
        Cartesian damping, N s/m and Nm s/rad. None: ``2 zeta sqrt(K_x diag(Lambda(q)))`` at each call.
    zeta : float
        Damping ratio when d is None.
    nullspace_damping : float or (7,)
        d_n, Nm s/rad: damps the self-motion of the redundant arm (default 5).
    nullspace_stiffness : float or (7,)
        k_n, Nm/rad, towards ``q_nullspace`` (default 0: damping only).
    q_nullspace : (7,) or None
        Preferred posture for the null-space stiffness.

    Call ``ctrl(q, dq, fMe_d, v_d=None) -> tau`` with fMe_d (4, 4) the goal pose of e in f and v_d (6,) the goal
    twist in f; returns (7,) Nm, gravity-free.
    """

    def __init__(self, model: FrankaModel, k_translation: Any = 500.0, k_rotation: Any = 30.0, d: Any = None,
                 zeta: float = 1.0, nullspace_damping: Any = 5.0, nullspace_stiffness: Any = 0.0,
                 q_nullspace: Any = None) -> None:
        self.model = _check_model(model)
        self.k = np.concatenate([_gains(k_translation, 3, "k_translation"), _gains(k_rotation, 3, "k_rotation")])
        self.d = None if d is None else _gains(d, 6, "d")
        if not (np.isfinite(zeta) and zeta >= 0):
            raise ValueError(f"zeta must be finite and >= 0, got {zeta}")
        self.zeta = float(zeta)
        self.dn = _gains(nullspace_damping, 7, "nullspace_damping")
        self.kn = _gains(nullspace_stiffness, 7, "nullspace_stiffness")
        self.q_nullspace = None if q_nullspace is None else as_vector(q_nullspace, 7, "q_nullspace")
        if self.kn.any() and self.q_nullspace is None:
            raise ValueError("nullspace_stiffness > 0 needs q_nullspace (the preferred posture)")

    def reset(self) -> None:
        """Stateless; present so every controller can be reset the same way."""

    def __call__(self, q: Any, dq: Any, fMe_d: Any, v_d: Any = None) -> np.ndarray:
        q, dq = as_vector(q, 7, "q"), as_vector(dq, 7, "dq")
        fMe_d = as_pose(fMe_d, "fMe_d")
        v_d = np.zeros(6) if v_d is None else as_vector(v_d, 6, "v_d")
        m = self.model
        J = m.fJe(q).copy()
        fMe = m.fMe(q)
        B = m.mass_matrix(q)
        N, Lam = null_space_projector(m, q, J, B)
        e = pose_error(fMe, fMe_d)
        d = self.d if self.d is not None else 2.0 * self.zeta * np.sqrt(self.k * np.clip(np.diag(Lam), 0, None))
        F = self.k * e + d * (v_d - J @ dq)
        tau0 = -self.dn * dq
        if self.q_nullspace is not None:
            tau0 = tau0 + self.kn * (self.q_nullspace - q)
        return J.T @ F + N.T @ tau0 + m.coriolis(q, dq)
