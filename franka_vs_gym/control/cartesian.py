"""Cartesian computed-torque control of the end effector (the left arm of the dual-arm "Franko" experiment).

    a    = a_d + Kd (v_d - v) + Kp e                                 task acceleration (6,), base frame f
    ddq  = Jbar (a - dJ dq) + N (kp_n (q_n - q) - kd_n dq)           Jbar = B^-1 J^T Lambda, N = I - Jbar J
    tau  = B(q) ddq + C(q, dq) dq + F(dq) [+ g(q) - g_internal(q)]   gravity-free (the robot adds g_internal(q))

e is :func:`~franka_vs_gym.control.impedance.pose_error` (m, rad), v = J dq with J = fJe (6, 7) the end-effector
twist [v; w] in f. With the exact model the closed loop is ``de'' + Kd de' + Kp e = 0`` per task coordinate; the
redundancy is resolved with the dynamically consistent inverse, the null-space posture term never moving e.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from franka_vs_gym.control.impedance import _check_model, _gains, pose_error
from franka_vs_gym.model.checks import as_pose, as_vector
from franka_vs_gym.model.franka_model import FrankaModel


class CartesianComputedTorque:
    """Operational-space computed torque with a smooth start.

    Parameters
    ----------
    model : FrankaModel
        The controller's model (B, C, friction, Jacobians); its errors are the controller's errors.
    kp : float or (6,)
        Task stiffness per coordinate [x, y, z, rx, ry, rz], 1/s^2 (default 400).
    kd : float, (6,) or None
        Task damping, 1/s (default 2 sqrt(kp), critical).
    kp_null, kd_null : float or (7,)
        Null-space posture gains, 1/s^2 and 1/s (default 25 and 10), towards ``q_nullspace``.
    q_nullspace : (7,) or None
        Preferred posture; None: the joint position at the first call.
    friction : bool
        Compensate the model friction F(dq).
    internal : FrankaModel or None
        The robot's own model (what its gravity compensation knows, e.g. ``FrankaSim.model``). When given, the
        command adds ``g_model(q) - g_internal(q)``: the gravity of a payload the controller knows about and the
        robot does not. None: the two agree.
    mu : float
        Smooth-start rate, 1/s: the command at the first call, tau0, is subtracted with weight exp(-mu t), so the
        command starts from zero as in eq. (2). 0 disables it.

    Call ``ctrl(t, q, dq, fMe_d, v_d=None, a_d=None) -> tau``: t in s, q (7,) rad, dq (7,) rad/s, fMe_d (4, 4) goal
    pose of e in f, v_d (6,) goal twist in f (m/s, rad/s), a_d (6,) goal acceleration in f; returns (7,) Nm.
    """

    def __init__(self, model: FrankaModel, kp: Any = 400.0, kd: Any = None, kp_null: Any = 25.0,
                 kd_null: Any = 10.0, q_nullspace: Any = None, friction: bool = True,
                 internal: FrankaModel | None = None, mu: float = 0.0) -> None:
        self.model = _check_model(model)
        self.internal = None if internal is None else _check_model(internal, "internal")
        self.kp = _gains(kp, 6, "kp")
        self.kd = _gains(2.0 * np.sqrt(self.kp) if kd is None else kd, 6, "kd")
        self.kp_null = _gains(kp_null, 7, "kp_null")
        self.kd_null = _gains(kd_null, 7, "kd_null")
        self._q_null_given = None if q_nullspace is None else as_vector(q_nullspace, 7, "q_nullspace")
        self.friction = bool(friction)
        if not (mu >= 0 and math.isfinite(mu)):
            raise ValueError(f"mu must be finite and >= 0, got {mu}")
        self.mu = float(mu)
        self.reset()

    def reset(self) -> None:
        """Forget the start time, tau0 and (if it was not given) the null-space posture."""
        self.q_nullspace = None if self._q_null_given is None else self._q_null_given.copy()
        self._t0: float | None = None
        self._tau0 = np.zeros(7)
        self.last_error = np.zeros(6)

    def __call__(self, t: float, q: Any, dq: Any, fMe_d: Any, v_d: Any = None, a_d: Any = None) -> np.ndarray:
        if not math.isfinite(t):
            raise ValueError(f"t must be finite, got {t}")
        q, dq = as_vector(q, 7, "q"), as_vector(dq, 7, "dq")
        fMe_d = as_pose(fMe_d, "fMe_d")
        v_d = np.zeros(6) if v_d is None else as_vector(v_d, 6, "v_d")
        a_d = np.zeros(6) if a_d is None else as_vector(a_d, 6, "a_d")
        if self.q_nullspace is None:
            self.q_nullspace = q.copy()
        m = self.model
        J = m.fJe(q).copy()
        dJ = m.fJe_dot(q, dq).copy()
        B = m.mass_matrix(q)
        e = pose_error(m.fMe(q), fMe_d)
        self.last_error = e
        a = a_d + self.kd * (v_d - J @ dq) + self.kp * e
        Binv_JT = np.linalg.solve(B, J.T)
        Lam = np.linalg.pinv(J @ Binv_JT, rcond=1e-6)
        Jbar = Binv_JT @ Lam
        N = np.eye(7) - Jbar @ J
        ddq = Jbar @ (a - dJ @ dq) + N @ (self.kp_null * (self.q_nullspace - q) - self.kd_null * dq)
        tau = B @ ddq + m.coriolis(q, dq)
        if self.friction:
            tau += m.friction(dq)
        if self.internal is not None:
            tau += m.gravity(q) - self.internal.gravity(q)
        if self.mu > 0:
            if self._t0 is None:
                self._t0, self._tau0 = float(t), tau.copy()
            tau = tau - self._tau0 * math.exp(-self.mu * (t - self._t0))
        return tau


def circle_reference(t: float, start: Any, radius: float, frequency: float, axis_u: Any = (0.0, 1.0, 0.0),
                     axis_v: Any = (0.0, 0.0, 1.0), ramp: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration (each (3,), m, m/s, m/s^2) on a circle of radius r in the plane (u, v).

    ``p(t) = c + r (u (cos(phi) - 1) + v sin(phi))`` with c = ``start`` and phase ``phi = 2 pi f s(t)``: the
    circle's centre is ``c - r u`` and it passes through ``c`` at t = 0, so the reference starts where the arm
    already is.
    ``ramp`` (s) > 0 ramps the angular rate up smoothly (quintic) over the first ``ramp`` seconds, so velocity and
    acceleration start from zero.
    """
    c, u, v = (as_vector(x, 3, n) for x, n in ((start, "start"), (axis_u, "axis_u"), (axis_v, "axis_v")))
    if not (radius >= 0 and frequency >= 0 and ramp >= 0):
        raise ValueError(f"radius, frequency and ramp must be >= 0, got {radius}, {frequency}, {ramp}")
    w = 2.0 * math.pi * frequency
    if ramp > 0 and t < ramp:
        # s(t): position of a quintic-ramped clock; ds = rate (0 -> 1), dds its derivative
        x = max(t, 0.0) / ramp
        ds = 10 * x**3 - 15 * x**4 + 6 * x**5
        dds = (30 * x**2 - 60 * x**3 + 30 * x**4) / ramp
        s = ramp * (2.5 * x**4 - 3 * x**5 + x**6)
    else:
        s = (t - ramp / 2.0) if ramp > 0 else t
        ds, dds = 1.0, 0.0
    phi, dphi, ddphi = w * s, w * ds, w * dds
    cp, sp = math.cos(phi), math.sin(phi)
    p = c + radius * (u * (cp - 1.0) + v * sp)
    dp = radius * dphi * (-u * sp + v * cp)
    ddp = radius * (ddphi * (-u * sp + v * cp) - dphi**2 * (u * cp + v * sp))
    return p, dp, ddp


__all__ = ["CartesianComputedTorque", "circle_reference"]
