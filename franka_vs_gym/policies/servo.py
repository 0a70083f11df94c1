"""Classical visual servoing as scripted policies: IBVS (4 tag corners) and PBVS (tag pose).

They consume the visual-servoing observation contract of docs/ARCHITECTURE.md (dict: ``q``, ``features``,
``features_desired``, ``feature_depth``, ``tag_pose``, ``tag_pose_desired``, ``visible``) and return a
``joint_velocity`` action (7,) rad/s (default) or a ``cartesian_velocity`` action (6,), the camera twist in c (m/s,
rad/s), clipped to the action bounds; with ``action_scale`` (the env's ``action_scale``, or
:meth:`with_action_scale`, which :func:`~franka_vs_gym.envs.evaluate.evaluate` calls for a normalized env) the
normalized action of that scale instead, saturated there with its direction kept. ``predict`` has the stable-
baselines3 signature, so classical control and RL agents are evaluated the same way. When the tag is not seen the
policy commands zero velocity.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from franka_vs_gym.control.visual_servo import (
    AdaptiveGain,
    InteractionMatrixType,
    camera_to_joint_velocity,
    ibvs_velocity,
    pbvs_velocity,
)
from franka_vs_gym.model.config import resolve_config
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.model.geometry import pose_from_vector
from franka_vs_gym.sim.robot import DEFAULT_eMc
from franka_vs_gym.vision.tags import tag_corners

ACTION_TYPES = ("joint_velocity", "cartesian_velocity")
CARTESIAN_BOUNDS = np.array([0.5, 0.5, 0.5, 1.0, 1.0, 1.0])
_KEYS = {"q": 7, "features": 8, "features_desired": 8, "feature_depth": 4, "tag_pose": 6, "tag_pose_desired": 6,
         "visible": 1}


def _read(observation: Any) -> dict[str, np.ndarray]:
    if not isinstance(observation, dict):
        raise ValueError(f"observation must be a dict with keys {tuple(_KEYS)}, got {type(observation).__name__}")
    missing = [k for k in _KEYS if k not in observation]
    if missing:
        raise ValueError(f"observation lacks {missing} (a visual-servoing observation with features is needed; "
                         "observation_type 'image' alone has no features)")
    out = {}
    for k, n in _KEYS.items():
        a = np.asarray(observation[k], dtype=np.float64).reshape(-1)
        if a.shape != (n,):
            raise ValueError(f"observation[{k!r}] must have shape ({n},), got {np.shape(observation[k])} "
                             "(vectorised envs: call predict on each env's observation)")
        if not np.isfinite(a).all():
            raise ValueError(f"observation[{k!r}] contains NaN or inf")
        out[k] = a
    return out


class _ServoPolicy:
    #: the physical value of an output of 1 per component (None: physical outputs); see with_action_scale
    action_scale: np.ndarray | None = None

    def with_action_scale(self, scale: Any) -> _ServoPolicy:
        """A copy whose actions are normalized by ``scale`` (an env's ``action_scale``; None: physical units)."""
        return _with_scale(self, scale)

    def __init__(self, action_type: str, gain: AdaptiveGain | float, eMc: Any, model: Any, robot: Any = None) -> None:
        if action_type not in ACTION_TYPES:
            raise ValueError(f"action_type must be one of {ACTION_TYPES}, got {action_type!r}")
        self.action_type = action_type
        self.gain = gain if isinstance(gain, AdaptiveGain) else AdaptiveGain.constant(float(gain))
        self.eMc = np.array(DEFAULT_eMc if eMc is None else eMc, dtype=np.float64)
        self.model = model if isinstance(model, FrankaModel) else FrankaModel(resolve_config(model, robot))
        self.dq_max = self.model.limits()["dq_max"]

    def reset(self) -> None:
        """Nothing to forget between episodes (the laws are static)."""

    def _camera_twist(self, o: dict[str, np.ndarray]) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError

    def predict(self, observation: dict[str, Any], state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """Action for one observation; returns ``(action, None)``."""
        o = _read(observation)
        if o["visible"][0] < 0.5:
            v_c = np.zeros(6)
        else:
            v_c = self._camera_twist(o)
        if self.action_type == "cartesian_velocity":
            out, bound = v_c, CARTESIAN_BOUNDS
        else:
            out, bound = camera_to_joint_velocity(v_c, self.model.eJe(o["q"]), self.eMc), self.dq_max
        scale = self.action_scale
        if scale is not None:
            bound = np.minimum(bound, scale)
        ratio = max(1.0, float(np.max(np.abs(out) / bound)))
        out = out / ratio
        if scale is not None:
            out = out / scale
        return out.astype(np.float32), None


def _with_scale(policy: Any, scale: Any) -> Any:
    """A shallow copy of a scripted policy with its action scale set (None: physical)."""
    import copy

    out = copy.copy(policy)
    out.action_scale = None if scale is None else np.array(scale, dtype=np.float64)
    return out


class IBVSPolicy(_ServoPolicy):
    """Image-based visual servoing on the 4 tag corners (point features, normalized coordinates).

    Parameters
    ----------
    action_type : "joint_velocity" (7,) or "cartesian_velocity" (6,)
    interaction : "CURRENT", "DESIRED" or "MEAN" interaction matrix (default MEAN, robust on large rotations)
    gain : AdaptiveGain or constant gain (1/s); default ViSP's adaptive gain (4, 0.4, 30)
    tag_size : side of the tag (m), for the desired corner depths
    eMc : camera mount (4x4); must be the environment's (default the simulator's default mount)
    model : the FrankaModel (or config/path) giving eJe
    robot : the arm ("fer", "fr3" or a RobotDescription) when ``model`` is not given; its joint velocity limits
        bound the action
    """

    def __init__(self, action_type: str = "joint_velocity", interaction: str = "MEAN",
                 gain: AdaptiveGain | float | None = None, tag_size: float = 0.08, eMc: Any = None,
                 model: Any = None, robot: Any = None) -> None:
        super().__init__(action_type, AdaptiveGain() if gain is None else gain, eMc, model, robot)
        self.interaction = InteractionMatrixType(interaction)
        self.tag_size = float(tag_size)
        self._corners = tag_corners(self.tag_size)
        self._Z_star: tuple[bytes, np.ndarray] | None = None

    def _desired_depth(self, tag_pose_desired: np.ndarray) -> np.ndarray:
        key = tag_pose_desired.tobytes()
        if self._Z_star is None or self._Z_star[0] != key:
            cdMo = pose_from_vector(tag_pose_desired)
            self._Z_star = (key, (self._corners @ cdMo[:3, :3].T + cdMo[:3, 3])[:, 2])
        return self._Z_star[1]

    def _camera_twist(self, o: dict[str, np.ndarray]) -> np.ndarray:
        Z = o["feature_depth"]
        Z = np.where(Z > 1e-3, Z, self._desired_depth(o["tag_pose_desired"]))
        v, _ = ibvs_velocity(o["features"], o["features_desired"], Z, self._desired_depth(o["tag_pose_desired"]),
                             self.interaction, self.gain)
        return v


class PBVSPolicy(_ServoPolicy):
    """Position-based visual servoing on (t, theta u) of cdMc from the estimated tag pose.

    Parameters as :class:`IBVSPolicy` (no interaction choice: the PBVS interaction matrix is exact)."""

    def __init__(self, action_type: str = "joint_velocity", gain: AdaptiveGain | float | None = None,
                 eMc: Any = None, model: Any = None, robot: Any = None) -> None:
        super().__init__(action_type, AdaptiveGain() if gain is None else gain, eMc, model, robot)

    def _camera_twist(self, o: dict[str, np.ndarray]) -> np.ndarray:
        v, _ = pbvs_velocity(pose_from_vector(o["tag_pose"]), pose_from_vector(o["tag_pose_desired"]), self.gain)
        return v
