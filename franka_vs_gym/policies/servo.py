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
    EyeToHandForm,
    InteractionMatrixType,
    camera_to_joint_velocity,
    ibvs_eye_to_hand,
    ibvs_velocity,
    pbvs_eye_to_hand,
    pbvs_velocity,
    spatial_jacobian,
)
from franka_vs_gym.model.config import resolve_config
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.model.geometry import inverse_pose, pose_from_vector, twist_transform
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

    def _joint_velocity(self, o: dict[str, np.ndarray], v_c: np.ndarray) -> np.ndarray:
        """The joint velocities (7,) realising the wrist camera's twist v_c."""
        return camera_to_joint_velocity(v_c, self.model.eJe(o["q"]), self.eMc)

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
            out, bound = self._joint_velocity(o, v_c), self.dq_max
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


class _EyeToHandPolicy(_ServoPolicy):
    """The eye-to-hand laws (:mod:`franka_vs_gym.control.visual_servo`): joint velocities from the features seen by
    a camera fixed in the world, the robot's Jacobian and the camera's placement ``camera_pose`` (fMc, from the
    observation: a calibrated camera)."""

    def __init__(self, gain: AdaptiveGain | float | None, form: str, eMo: Any, model: Any, robot: Any) -> None:
        super().__init__("joint_velocity", AdaptiveGain() if gain is None else gain, None, model, robot)
        self.form = EyeToHandForm(form)
        from franka_vs_gym.envs.eye_to_hand import DEFAULT_eMo

        self.eMo = np.array(DEFAULT_eMo if eMo is None else eMo, dtype=np.float64)

    def _frames(self, o: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        if "camera_pose" not in o:
            raise ValueError("observation lacks 'camera_pose' (an eye-to-hand environment's observation is needed)")
        cMf = inverse_pose(pose_from_vector(o["camera_pose"]))
        q = o["q"]
        eJe = self.model.eJe(q)
        fMe = self.model.fMe(q)
        if self.form == EyeToHandForm.cVe_eJe:
            return {"cVe": twist_transform(cMf @ fMe), "eJe": eJe}
        if self.form == EyeToHandForm.cVf_fVe_eJe:
            return {"cVf": twist_transform(cMf), "fVe": twist_transform(fMe), "eJe": eJe}
        return {"cVf": twist_transform(cMf), "fJe": spatial_jacobian(fMe, eJe)}

    def predict(self, observation: dict[str, Any], state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        """Action for one observation; returns ``(action, None)``."""
        if not isinstance(observation, dict) or "camera_pose" not in observation:
            raise ValueError("observation lacks 'camera_pose' (an eye-to-hand environment's observation is needed)")
        pose = np.asarray(observation["camera_pose"], dtype=np.float64).reshape(-1)
        if pose.shape != (6,) or not np.isfinite(pose).all():
            raise ValueError(f"observation['camera_pose'] must be 6 finite numbers (fMc: t, theta u), got "
                             f"{np.shape(observation['camera_pose'])}")
        self._camera_pose = pose
        return super().predict(observation, state, episode_start, deterministic)

    def _camera_twist(self, o: dict[str, np.ndarray]) -> np.ndarray:
        return np.zeros(6)  # (the camera does not move: the laws give joint velocities directly)

    def _joint_velocity(self, o: dict[str, np.ndarray], v_c: np.ndarray) -> np.ndarray:
        if o["visible"][0] < 0.5:
            return np.zeros(7)
        o = {**o, "camera_pose": self._camera_pose}
        return self._law(o)

    def _law(self, o: dict[str, np.ndarray]) -> np.ndarray:  # pragma: no cover - overridden
        raise NotImplementedError


class IBVSEyeToHandPolicy(_EyeToHandPolicy):
    """Eye-to-hand IBVS on the 4 tag corners (FrankaIBVSEyeToHand-v0): ``dq = -lambda J^+ (s - s*)`` with ViSP's
    task Jacobian ``J = -L cVa aJe`` (``form``: "EYETOHAND_L_cVe_eJe" (default), "EYETOHAND_L_cVf_fVe_eJe" or
    "EYETOHAND_L_cVf_fJe").

    Parameters: ``interaction`` ("CURRENT", "DESIRED", "MEAN" (default)), ``gain`` (default ViSP's adaptive gain
    (4, 0.4, 30)), ``form``, ``tag_size`` (m), ``eMo`` (the tag on the hand; default the environment's), ``model`` /
    ``robot`` (the arm, for its Jacobian and velocity limits). Joint-velocity actions (7,) rad/s."""

    def __init__(self, interaction: str = "MEAN", gain: AdaptiveGain | float | None = None,
                 form: str = "EYETOHAND_L_cVe_eJe", tag_size: float = 0.08, eMo: Any = None, model: Any = None,
                 robot: Any = None) -> None:
        super().__init__(gain, form, eMo, model, robot)
        self.interaction = InteractionMatrixType(interaction)
        self._corners = tag_corners(float(tag_size))

    def _law(self, o: dict[str, np.ndarray]) -> np.ndarray:
        cdMo = pose_from_vector(o["tag_pose_desired"])
        Z_star = (self._corners @ cdMo[:3, :3].T + cdMo[:3, 3])[:, 2]
        Z = np.where(o["feature_depth"] > 1e-3, o["feature_depth"], Z_star)
        dq, _ = ibvs_eye_to_hand(o["features"], o["features_desired"], Z, Z_star, self.interaction, self.gain,
                                 self.form, **self._frames(o))
        return dq


class PBVSEyeToHandPolicy(_EyeToHandPolicy):
    """Eye-to-hand PBVS on (t, theta u) of cdMc = cdMo cMo^-1 (FrankaPBVSEyeToHand-v0), with ViSP's task Jacobian
    ``J = -L cVa aJe``; parameters as :class:`IBVSEyeToHandPolicy` (no interaction choice)."""

    def __init__(self, gain: AdaptiveGain | float | None = None, form: str = "EYETOHAND_L_cVe_eJe", eMo: Any = None,
                 model: Any = None, robot: Any = None) -> None:
        super().__init__(gain, form, eMo, model, robot)

    def _law(self, o: dict[str, np.ndarray]) -> np.ndarray:
        dq, _ = pbvs_eye_to_hand(pose_from_vector(o["tag_pose"]), pose_from_vector(o["tag_pose_desired"]),
                                 self.gain, self.form, **self._frames(o))
        return dq
