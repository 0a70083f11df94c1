"""Scripted torque policies for the torque-tracking environments (FrankaTorqueTracking-v0).

They consume the observation contract of docs/ARCHITECTURE.md (dict, float32): ``q``, ``dq``, ``q_desired``,
``dq_desired``, ``ddq_desired`` (7,) and ``time`` (1,) in s since the episode start, and return the ``torque``
action: (7,) float32, Nm, gravity-free (the robot adds g(q)), clipped to the robot's torque limits. Their
``predict`` has the stable-baselines3 signature, so classical control and RL agents are evaluated the same way::

    policy = ComputedTorquePolicy(env.unwrapped.robot.model)
    action, _ = policy.predict(obs)
"""

from __future__ import annotations

from typing import Any

import numpy as np

from franka_vs_gym.control.computed_torque import ComputedTorque
from franka_vs_gym.control.impedance import JointImpedance
from franka_vs_gym.model.config import resolve_config
from franka_vs_gym.model.franka_model import FrankaModel

OBSERVATION_KEYS = ("q", "dq", "q_desired", "dq_desired", "ddq_desired", "time")


def _as_model(model: Any, robot: Any = None) -> FrankaModel:
    """FrankaModel from a FrankaModel, ModelConfig, model-file path or None (the default configuration of
    ``robot``, the FER + hand when None)."""
    if isinstance(model, FrankaModel):
        return model
    try:
        return FrankaModel(resolve_config(model, robot))
    except TypeError as e:
        raise ValueError(f"model: {e}") from None


def _read(observation: Any) -> dict[str, np.ndarray]:
    if not isinstance(observation, dict):
        raise ValueError(f"observation must be a dict with keys {OBSERVATION_KEYS}, got {type(observation).__name__}"
                         " (vectorised envs: pass one env's observation, or use predict on each)")
    missing = [k for k in OBSERVATION_KEYS if k not in observation]
    if missing:
        raise ValueError(f"observation lacks {missing}; a torque-tracking observation has {OBSERVATION_KEYS}")
    out = {}
    for k in OBSERVATION_KEYS:
        a = np.asarray(observation[k], dtype=np.float64).reshape(-1)
        n = 1 if k == "time" else 7
        if a.shape != (n,):
            raise ValueError(f"observation[{k!r}] must have shape ({n},), got {np.shape(observation[k])}")
        if not np.isfinite(a).all():
            raise ValueError(f"observation[{k!r}] contains NaN or inf")
        out[k] = a
    return out


class _TorquePolicy:
    """Shared episode handling: the controller is reset at an episode start (``episode_start`` true, or the
    observation's time going backwards)."""

    controller: Any
    #: the torque (7,) Nm of an output of 1 (None: outputs in Nm); see with_action_scale
    action_scale: np.ndarray | None = None

    def with_action_scale(self, scale: Any) -> _TorquePolicy:
        """A copy whose actions are normalized by ``scale`` (an env's ``action_scale``, Nm; None: Nm): the torque
        clipped at the scale (with ``clip``) and divided by it."""
        from franka_vs_gym.policies.servo import _with_scale

        return _with_scale(self, scale)

    def __init__(self, clip: bool) -> None:
        self.clip = bool(clip)
        self._last_time: float | None = None

    def _set_limits(self) -> None:
        """Torque limits (7,) Nm of the controller's robot (the env's action bounds)."""
        self.tau_max = self.controller.model.limits()["tau_max"]

    def _controller_reset(self) -> None:  # pragma: no cover - overridden
        raise NotImplementedError

    def _torque(self, o: dict[str, np.ndarray]) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def reset(self) -> None:
        """Start a new episode."""
        self._last_time = None
        self._controller_reset()

    def predict(self, observation: dict[str, Any], state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """Torque action (7,) float32, Nm, gravity-free, for one observation; returns ``(action, None)``."""
        o = _read(observation)
        t = float(o["time"][0])
        if (episode_start is not None and bool(np.any(episode_start))) or (
                self._last_time is not None and t < self._last_time):
            self.reset()
        self._last_time = t
        tau = self._torque(o)
        scale = self.action_scale
        if self.clip:
            hi = self.tau_max if scale is None else np.minimum(self.tau_max, scale)
            tau = np.clip(tau, -hi, hi)
        if scale is not None:
            tau = tau / scale
        return tau.astype(np.float32), None


class ComputedTorquePolicy(_TorquePolicy):
    """Joint computed torque with PID and smooth start (eq. (2) of the FrankaSim paper) as a policy.

    Parameters
    ----------
    model : FrankaModel, ModelConfig, model-file path or None
        The controller's model (None: the default FER + Franka Hand, or the default ``robot``).
    robot : the arm ("fer", "fr3" or a RobotDescription) when ``model`` is not given
    kp, kd, ki, mu, friction :
        As :class:`franka_vs_gym.control.ComputedTorque` (Kp 400, 900 on joint 7; Kd critical; mu 4 1/s).
    clip : bool
        Clip the action to the robot's torque limits (the env's action bounds).
    """

    def __init__(self, model: Any = None, kp: Any = None, kd: Any = None, ki: Any = 0.0, mu: float = 4.0,
                 friction: bool = True, clip: bool = True, robot: Any = None) -> None:
        super().__init__(clip)
        self.controller = ComputedTorque(_as_model(model, robot), kp=kp, kd=kd, ki=ki, mu=mu, friction=friction)
        self._set_limits()

    def _controller_reset(self) -> None:
        self.controller.reset()

    def _torque(self, o: dict[str, np.ndarray]) -> np.ndarray:
        return self.controller(float(o["time"][0]), o["q"], o["dq"], o["q_desired"], o["dq_desired"],
                               o["ddq_desired"])


class JointImpedancePolicy(_TorquePolicy):
    """Joint impedance (spring-damper to the desired trajectory, Coriolis and inertial feed-forward) as a policy.

    By default every joint gets the same bandwidth: ``k_i = omega^2 B_ii(q)``, ``d_i = 2 zeta omega B_ii(q)`` with
    ``natural_frequency`` omega = 10 rad/s, stable at the tracking env's default 100 Hz as well as at 1 kHz. Pass
    ``k`` for a fixed libfranka-style stiffness (natural_frequency is then ignored), e.g.
    ``JointImpedance.DEFAULT_K`` (600 ... 50 Nm/rad): a 1 kHz design whose light wrist joints go unstable under a
    100 Hz zero-order hold.

    Parameters
    ----------
    model : FrankaModel, ModelConfig, model-file path or None
    robot : the arm ("fer", "fr3" or a RobotDescription) when ``model`` is not given
    k, d, zeta, friction, natural_frequency :
        As :class:`franka_vs_gym.control.JointImpedance` (stiffness Nm/rad, damping Nm s/rad, omega rad/s).
    feedforward : bool
        Add ``B(q) ddq_desired`` (default True).
    clip : bool
        Clip the action to the robot's torque limits.
    """

    def __init__(self, model: Any = None, k: Any = None, d: Any = None, zeta: float = 1.0,
                 feedforward: bool = True, friction: bool = True, natural_frequency: float | None = 10.0,
                 clip: bool = True, robot: Any = None) -> None:
        super().__init__(clip)
        if k is None and natural_frequency is None:
            raise ValueError("give a stiffness k or a natural_frequency")
        self.controller = JointImpedance(_as_model(model, robot), k=JointImpedance.DEFAULT_K if k is None else k, d=d,
                                         zeta=zeta, friction=friction,
                                         natural_frequency=None if k is not None else natural_frequency)
        self.feedforward = bool(feedforward)
        self._set_limits()

    def _controller_reset(self) -> None:
        self.controller.reset()

    def _torque(self, o: dict[str, np.ndarray]) -> np.ndarray:
        return self.controller(o["q"], o["dq"], o["q_desired"], o["dq_desired"],
                               o["ddq_desired"] if self.feedforward else None)


__all__ = ["ComputedTorquePolicy", "JointImpedancePolicy", "OBSERVATION_KEYS"]
