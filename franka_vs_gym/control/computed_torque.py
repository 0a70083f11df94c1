"""Joint-space computed-torque control with PID and smooth start (eq. (2) of the FrankaSim paper).

    tau = B(q) (Kp e + Kd de + Ki int(e) + ddq_d) + C(q, dq) dq + F(dq) - tau0 exp(-mu t),   e = q_d - q

tau is gravity-free (the robot adds g(q), as libfranka), tau0 is the torque computed at the first call (t = t0),
so the command starts from zero and the transient decays with rate mu.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from franka_vs_gym.model.franka_model import FrankaModel


def _gains(x: Any, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(x, dtype=np.float64), (7,)).copy()
    if not np.isfinite(a).all() or (a < 0).any():
        raise ValueError(f"{name} gains must be finite and >= 0, got {a}")
    return a


def _joint(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != (7,):
        raise ValueError(f"{name} must have shape (7,), got {a.shape}")
    if not np.isfinite(a).all():
        raise ValueError(f"{name} contains NaN or inf: {a}")
    return a


class ComputedTorque:
    """Computed-torque controller of eq. (2).

    Parameters
    ----------
    model : FrankaModel
        The controller's model (B, C, friction). Its errors are the controller's errors.
    kp, kd, ki : float or (7,)
        PID gains (1/s^2, 1/s, 1/s^3). Defaults follow the ViSP Franka tutorials: Kp 400 (900 on joint 7),
        Kd = 2 sqrt(Kp) (critical damping), Ki 0 unless given.
    mu : float
        Rate of the smooth start, 1/s (4 in the paper's experiment).
    friction : bool
        Compensate the model's friction F(dq).
    """

    def __init__(self, model: FrankaModel, kp: Any = None, kd: Any = None, ki: Any = 0.0, mu: float = 4.0,
                 friction: bool = True) -> None:
        self.model = model
        self.kp = _gains([400.0] * 6 + [900.0] if kp is None else kp, "kp")
        self.kd = _gains(2.0 * np.sqrt(self.kp) if kd is None else kd, "kd")
        self.ki = _gains(ki, "ki")
        if not (mu >= 0 and math.isfinite(mu)):
            raise ValueError(f"mu must be >= 0, got {mu}")
        self.mu = float(mu)
        self.friction = friction
        self.reset()

    def reset(self) -> None:
        """Forget the integral, the start time and tau0 (the next call is t = t0)."""
        self._t0: float | None = None
        self._t_last: float | None = None
        self._int = np.zeros(7)
        self._tau0 = np.zeros(7)

    def __call__(self, t: float, q: np.ndarray, dq: np.ndarray, q_d: np.ndarray, dq_d: np.ndarray,
                 ddq_d: np.ndarray) -> np.ndarray:
        """Gravity-free joint torque command (7,), Nm, at time t (s).

        q, q_d in rad, dq, dq_d in rad/s, ddq_d in rad/s^2, each (7,); wrong shapes or NaN raise ValueError.
        """
        if not math.isfinite(t):
            raise ValueError(f"t must be finite, got {t}")
        q, dq, q_d, dq_d, ddq_d = (_joint(x, n) for x, n in ((q, "q"), (dq, "dq"), (q_d, "q_d"), (dq_d, "dq_d"),
                                                              (ddq_d, "ddq_d")))
        e = q_d - q
        de = dq_d - dq
        if self._t_last is not None:
            self._int += e * (t - self._t_last)
        self._t_last = t
        v = self.kp * e + self.kd * de + self.ki * self._int + ddq_d
        m = self.model
        tau = m.mass_matrix(q) @ v + m.coriolis(q, dq)
        if self.friction:
            tau += m.friction(dq)
        if self._t0 is None:
            self._t0 = t
            self._tau0 = tau.copy()
        return tau - self._tau0 * math.exp(-self.mu * (t - self._t0))
