"""The robot interface's rate limiter: the limits libfranka applies to every command by default (``limit_rate``).

libfranka, the client library of the Franka Control Interface, passes each command of a control loop through
``franka::limitRate`` before sending it, unless the user switches it off (``limit_rate = false``): a command then
changes, per 1 ms cycle, no faster than the published limits of its control mode allow, so an in-range command
does not trip the robot's motion-generator or torque-discontinuity reflexes. This module is that limiter as pure
numpy functions, with the same semantics (reference: libfranka's ``include/franka/rate_limiting.h`` and
``src/rate_limiting.cpp``, Apache-2.0; the limits are those published on the FCI documentation's "Robot and
interface specifications" page for the FER and the FR3):

- torque (:func:`limit_torque_rate`): each joint's torque moves towards the command by at most ``max_rate * dt``;
- joint velocity (:func:`limit_joint_velocity`): the command is differentiated to a jerk, the jerk clipped, the
  resulting acceleration clipped to what still lets the velocity stay within its (upper, lower) limits
  (``(max_jerk / max_acceleration) * (limit - v)``) and to the acceleration limit, then integrated;
- joint position (:func:`limit_joint_position`): the same on the velocity implied by the position step;
- Cartesian velocity (:func:`limit_cartesian_velocity`) and pose (:func:`limit_cartesian_pose`): the same per
  3-vector (translation, rotation), with norms instead of components.

Velocity limits: the FER's are constants (rated velocity minus a tolerance for three lost packets); the FR3's
depend on the commanded joint position (:func:`fr3_joint_velocity_limits`: zero at the position limit, so a
rate-limited FR3 command stops before it). Each robot's set is a :class:`RateLimits` (:data:`FER_LIMITS`,
:data:`FR3_LIMITS`, :func:`rate_limits`).

The limiter is a filter on commands, stateful through the *last commanded* values (velocity, acceleration,
position); :class:`JointRateLimiter` keeps that state for one robot's joint-velocity or torque commands, one cycle at
a time, as the simulated robot applies it at every physics step (``FrankaSim(command_rates="limit")``; the compiled
plant runs the same arithmetic in C, ``franka_vs_gym/sim/_plant.c``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: libfranka's control cycle (s): derivatives are per 1 ms.
CYCLE = 1e-3
#: libfranka's margin below each published limit (``kLimitEps``).
LIMIT_EPS = 1e-3
#: Below this norm a Cartesian acceleration or jerk is not limited (libfranka's ``kNormEps``, double epsilon).
NORM_EPS = float(np.finfo(np.float64).eps)
#: The Cartesian-pose interface scales the rotational limits by this factor.
POSE_ROTATION_FACTOR = 0.99


def _vec7(x, name: str) -> np.ndarray:
    a = np.array(x, dtype=np.float64)
    if a.shape != (7,) or not np.isfinite(a).all():
        raise ValueError(f"{name} must be 7 finite numbers, got {x!r}")
    return a


@dataclass(frozen=True)
class RateLimits:
    """One robot's rate-limiter limits (SI units), libfranka's constants with their margins already applied.

    Joint velocity limits are ``clip(offset + sqrt(max(0, k (q_limit - q))), 0, cap) - tolerance`` above and the
    mirror image below (per joint): with ``k = 0`` a constant ``cap - tolerance`` (the FER), otherwise the FR3's
    position-dependent limit that reaches zero at the joint's position limit."""

    name: str
    torque_rate: np.ndarray  # Nm/s
    joint_acceleration: np.ndarray  # rad/s^2
    joint_jerk: np.ndarray  # rad/s^3
    velocity_cap: np.ndarray  # rad/s (upper; the lower is its negative)
    velocity_offset: np.ndarray  # rad/s (upper; the lower uses its negative)
    velocity_k: np.ndarray  # 1/s^2 (0: constant limits)
    q_upper: np.ndarray  # rad: where the upper velocity limit is zero
    q_lower: np.ndarray  # rad: where the lower velocity limit is zero
    velocity_tolerance: np.ndarray  # rad/s
    translation: tuple[float, float, float]  # (velocity m/s, acceleration m/s^2, jerk m/s^3)
    rotation: tuple[float, float, float]  # (velocity rad/s, acceleration rad/s^2, jerk rad/s^3)
    sources: str = field(default="", compare=False)

    def joint_velocity_limits(self, q_d) -> tuple[np.ndarray, np.ndarray]:
        """(upper, lower) joint velocity limits (7,) rad/s at the commanded joint position ``q_d`` (7,) rad."""
        q = np.asarray(q_d, dtype=np.float64)
        k = self.velocity_k
        up = np.minimum(self.velocity_cap, np.maximum(0.0, self.velocity_offset +
                                                      np.sqrt(np.maximum(0.0, k * (self.q_upper - q)))))
        lo = np.maximum(-self.velocity_cap, np.minimum(0.0, -self.velocity_offset -
                                                       np.sqrt(np.maximum(0.0, k * (q - self.q_lower)))))
        return up - self.velocity_tolerance, lo + self.velocity_tolerance

    def plant_columns(self) -> np.ndarray:
        """(7, 9) per-joint numbers of the compiled plant's limiter (``franka_vs_gym.sim.plant.LCOL`` columns on):
        torque rate, acceleration, jerk, velocity cap, offset, k, q_upper, q_lower, tolerance."""
        return np.stack([self.torque_rate, self.joint_acceleration, self.joint_jerk, self.velocity_cap,
                         self.velocity_offset, self.velocity_k, self.q_upper, self.q_lower,
                         self.velocity_tolerance], axis=1)


def _fer() -> RateLimits:
    acc = np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0]) - LIMIT_EPS
    jerk = np.array([7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0]) - LIMIT_EPS
    packets_lost = 3.0  # libfranka's FER tolerance: a constant-acceleration model over 3 lost packets
    vel = np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61]) - LIMIT_EPS - packets_lost * CYCLE * acc
    big = np.full(7, 1e9)
    return RateLimits("fer", np.full(7, 1000.0 - LIMIT_EPS), acc, jerk, vel, vel.copy(), np.zeros(7), big, -big,
                      np.zeros(7), (1.7 - LIMIT_EPS - packets_lost * CYCLE * (13.0 - LIMIT_EPS), 13.0 - LIMIT_EPS,
                                    6500.0 - LIMIT_EPS),
                      (2.5 - LIMIT_EPS - packets_lost * CYCLE * (25.0 - LIMIT_EPS), 25.0 - LIMIT_EPS,
                       12500.0 - LIMIT_EPS),
                      "FCI documentation, limits for Panda (FER); libfranka 0.9 rate_limiting.h constants")


def _fr3() -> RateLimits:
    # position-based velocity limits of the FR3: v_max(q) = min(cap, max(0, offset + sqrt(k (q_max - q)))) with
    # k = 2 * the joint's deceleration limit (published values; libfranka 0.10+ rate_limiting.h)
    cap = np.array([2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26])
    off = -np.array([0.30, 0.20, 0.20, 0.30, 0.35, 0.35, 0.35])
    k = np.array([12.0, 5.17, 7.00, 8.00, 34.0, 11.0, 34.0])
    q_up = np.array([2.75010, 1.79180, 2.90650, -0.1458, 2.81010, 4.52050, 3.01960])
    q_lo = np.array([-2.750100, -1.791800, -2.906500, -3.048100, -2.810100, 0.54092, -3.019600])
    return RateLimits("fr3", np.full(7, 1000.0 - LIMIT_EPS), np.full(7, 10.0 - LIMIT_EPS),
                      np.full(7, 5000.0 - LIMIT_EPS), cap, off, k, q_up, q_lo, np.full(7, LIMIT_EPS),
                      (3.0 - LIMIT_EPS, 9.0 - LIMIT_EPS, 4500.0 - LIMIT_EPS),
                      (2.5 - LIMIT_EPS, 17.0 - LIMIT_EPS, 8500.0 - LIMIT_EPS),
                      "FCI documentation, limits for Franka Research 3; libfranka 0.10+ rate_limiting.h constants")


FER_LIMITS = _fer()
FR3_LIMITS = _fr3()
_BY_NAME = {"fer": FER_LIMITS, "fr3": FR3_LIMITS}


def rate_limits(robot) -> RateLimits:
    """The limiter's limits of a robot (a RobotDescription, or its name "fer"/"fr3"); other arms get the FER's."""
    name = robot if isinstance(robot, str) else getattr(robot, "name", "fer")
    return _BY_NAME.get(str(name).lower(), FER_LIMITS)


def fr3_joint_velocity_limits(q_d) -> tuple[np.ndarray, np.ndarray]:
    """(upper, lower) FR3 joint velocity limits (7,) rad/s at the commanded position ``q_d`` (7,) rad."""
    return FR3_LIMITS.joint_velocity_limits(q_d)


def _finite(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if not np.isfinite(a).all():
        raise ValueError(f"{name} is infinite or NaN: {a}")
    return a


# ---------------------------------------------------------------------------------------------------- per joint
def limit_torque_rate(tau, last_tau, max_rate, dt: float = CYCLE) -> np.ndarray:
    """The torque command rate-limited: ``last + clip((tau - last) / dt, -max_rate, max_rate) dt`` (Nm)."""
    tau = _finite(tau, "commanded torque")
    last = np.asarray(last_tau, dtype=np.float64)
    r = np.asarray(max_rate, dtype=np.float64)
    return last + np.clip((tau - last) / dt, -r, r) * dt


def limit_joint_velocity(dq, last_dq, last_ddq, upper, lower, max_acceleration, max_jerk,
                         dt: float = CYCLE) -> np.ndarray:
    """The joint velocity command (rad/s) rate-limited, per component (libfranka's scalar law, vectorised):

    jerk = ((dq - last_dq) / dt - last_ddq) / dt, clipped to +-max_jerk; acceleration = last_ddq + jerk dt,
    clipped to [max(-A, (J/A)(lower - last_dq)), min(A, (J/A)(upper - last_dq))]; result last_dq + acc dt."""
    dq = _finite(dq, "commanded velocity")
    v, a = np.asarray(last_dq, dtype=np.float64), np.asarray(last_ddq, dtype=np.float64)
    A, J = np.asarray(max_acceleration, dtype=np.float64), np.asarray(max_jerk, dtype=np.float64)
    jerk = ((dq - v) / dt - a) / dt
    acc = a + np.clip(jerk, -J, J) * dt
    hi = np.minimum((J / A) * (np.asarray(upper, dtype=np.float64) - v), A)
    lo = np.maximum((J / A) * (np.asarray(lower, dtype=np.float64) - v), -A)
    return v + np.maximum(np.minimum(acc, hi), lo) * dt


def limit_joint_position(q, last_q, last_dq, last_ddq, upper, lower, max_acceleration, max_jerk,
                         dt: float = CYCLE) -> np.ndarray:
    """The joint position command (rad) rate-limited: the velocity of the step ``(q - last_q) / dt`` through
    :func:`limit_joint_velocity`, integrated from ``last_q``."""
    q = _finite(q, "commanded position")
    last_q = np.asarray(last_q, dtype=np.float64)
    return last_q + limit_joint_velocity((q - last_q) / dt, last_dq, last_ddq, upper, lower, max_acceleration,
                                         max_jerk, dt) * dt


# ---------------------------------------------------------------------------------------------------- Cartesian
def _limit_vector(max_v: float, max_a: float, max_j: float, v, last_v, last_a, dt: float) -> np.ndarray:
    """A 3-vector velocity limited in norm: jerk, then the acceleration along its own direction, bounded so that
    the velocity reachable in that direction stays within ``max_v`` (libfranka's Cartesian law)."""
    v, last_v, last_a = (np.asarray(x, dtype=np.float64) for x in (v, last_v, last_a))
    jerk = ((v - last_v) / dt - last_a) / dt
    acc = last_a.copy()
    nj = float(np.linalg.norm(jerk))
    if nj > NORM_EPS:
        acc = acc + jerk / nj * min(nj, max_j) * dt
    na = float(np.linalg.norm(acc))
    out = last_v.copy()
    if na > NORM_EPS:
        u = acc / na
        dot = float(u @ last_v)
        distance = -dot + np.sqrt(dot * dot - float(last_v @ last_v) + max_v * max_v)
        safe = min((max_j / max_a) * distance, max_a)
        out = out + u * min(na, safe) * dt
    return out


def limit_cartesian_velocity(twist, last_twist, last_acceleration, limits: RateLimits = FER_LIMITS,
                             dt: float = CYCLE) -> np.ndarray:
    """The end-effector twist (6,) ``[v; w]`` (m/s, rad/s) rate-limited, translation and rotation each in norm."""
    twist = _finite(twist, "commanded twist")
    lt, la = np.asarray(last_twist, dtype=np.float64), np.asarray(last_acceleration, dtype=np.float64)
    return np.concatenate([_limit_vector(*limits.translation, twist[:3], lt[:3], la[:3], dt),
                           _limit_vector(*limits.rotation, twist[3:], lt[3:], la[3:], dt)])


def limit_cartesian_pose(T, last_T, last_twist, last_acceleration, limits: RateLimits = FER_LIMITS,
                         dt: float = CYCLE) -> np.ndarray:
    """The end-effector pose command (4, 4) rate-limited: the twist of the step (translation difference and the
    rotation vector of ``R last_R^T``, per ``dt``) through :func:`limit_cartesian_velocity` with the rotational
    limits scaled by :data:`POSE_ROTATION_FACTOR`, integrated from ``last_T`` (rotation by the exponential map)."""
    from scipy.spatial.transform import Rotation

    T = _finite(T, "commanded pose")
    last_T = np.asarray(last_T, dtype=np.float64)
    if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]) or \
            not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
        raise ValueError("commanded pose must be a 4x4 homogeneous transformation")
    dx = np.empty(6)
    dx[:3] = (T[:3, 3] - last_T[:3, 3]) / dt
    dx[3:] = Rotation.from_matrix(T[:3, :3] @ last_T[:3, :3].T).as_rotvec() / dt
    f = POSE_ROTATION_FACTOR
    scaled = RateLimits(**{**limits.__dict__, "rotation": tuple(f * x for x in limits.rotation)})
    dx = limit_cartesian_velocity(dx, last_twist, last_acceleration, scaled, dt)
    out = np.eye(4)
    out[:3, 3] = last_T[:3, 3] + dx[:3] * dt
    out[:3, :3] = Rotation.from_rotvec(dx[3:] * dt).as_matrix() @ last_T[:3, :3]
    return out


# ---------------------------------------------------------------------------------------------------- stateful
class JointRateLimiter:
    """One robot's limiter state for joint-velocity or torque commands, advanced one cycle at a time.

    ``velocity(target)`` returns the next rate-limited joint velocity command (rad/s) and advances the last commanded
    velocity, acceleration and position (the commanded position integrates the limited velocities: the FR3's
    velocity limits depend on it, as libfranka's on ``q_d``); ``torque(target)`` the next rate-limited torque (Nm).
    ``dt`` is the cycle (s): the simulated robot runs one per physics step."""

    def __init__(self, limits: RateLimits, dt: float = CYCLE) -> None:
        self.limits = limits
        self.dt = float(dt)
        self.last = np.zeros(7)  # last command (rad/s or Nm)
        self.last_acc = np.zeros(7)  # last commanded acceleration (rad/s^2)
        self.q_d = np.zeros(7)  # commanded position (rad)

    def reset(self, q_d, last=None) -> None:
        """Start from rest at the commanded position ``q_d`` (or, torque control, from the torque ``last``)."""
        self.q_d[:] = q_d
        self.last[:] = 0.0 if last is None else last
        self.last_acc[:] = 0.0

    def velocity(self, target) -> np.ndarray:
        L = self.limits
        up, lo = L.joint_velocity_limits(self.q_d)
        v = limit_joint_velocity(target, self.last, self.last_acc, up, lo, L.joint_acceleration, L.joint_jerk,
                                 self.dt)
        self.last_acc[:] = (v - self.last) / self.dt
        self.last[:] = v
        self.q_d += v * self.dt
        return v

    def torque(self, target) -> np.ndarray:
        tau = limit_torque_rate(target, self.last, self.limits.torque_rate, self.dt)
        self.last[:] = tau
        return tau


__all__ = ["CYCLE", "FER_LIMITS", "FR3_LIMITS", "JointRateLimiter", "LIMIT_EPS", "NORM_EPS", "POSE_ROTATION_FACTOR",
           "RateLimits", "fr3_joint_velocity_limits", "limit_cartesian_pose", "limit_cartesian_velocity",
           "limit_joint_position", "limit_joint_velocity", "limit_torque_rate", "rate_limits"]
