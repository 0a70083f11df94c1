"""Wrappers and adapters for learning agents on the visual-servoing environments.

RL algorithms learn best with actions in [-1, 1] and a flat, roughly unit-scaled observation vector, while the
environments speak physical units and the dict contract shared with the classical policies. This module bridges
the two, in both directions:

- :class:`ScaledAction` and :class:`ServoVectorObservation` wrap an environment for training;
- :class:`AgentPolicy` wraps a trained stable-baselines3 model so that it takes the *contract* observation and
  returns a *physical* action, exactly like ``franka_vs_gym.policies.IBVSPolicy``;
  ``evaluate(agent, "FrankaIBVS-v0")`` then runs the agent and the classical controller on the same, unwrapped
  environment.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

OBS_LAYOUT = "servo-vector/2"
#: the servo vector followed by the pose error of the tag (the PBVS agents: their success is judged on the pose)
POSE_LAYOUT = "servo-pose-vector/1"
#: the pixel agent's layout (franka_vs_gym.envs.pixels.IMAGE_LAYOUT: the camera image, q and dq)
IMAGE_LAYOUT = "image-q-dq/1"
OBS_LAYOUTS = (OBS_LAYOUT, POSE_LAYOUT, IMAGE_LAYOUT)
VECTOR_SIZE = 8 + 8 + 1 + 8 + 4 + 7 + 7 + 1
POSE_VECTOR_SIZE = VECTOR_SIZE + 3 + 3 + 2


def servo_vector(obs: dict[str, Any]) -> np.ndarray:
    """Flat float32 vector (44,) from a visual-servoing contract observation (one env, not batched):

    ``4 e``, ``e / (||e|| + 0.005)`` (the error direction, which stays informative close to the goal),
    ``log10(||e|| + 0.001) / 3``, ``s``, ``5 (Z - Z*)``, ``q``, ``0.5 dq``, ``visible``, with ``e = s - s*``. The
    scales bring each part to about unit size."""
    s = np.asarray(obs["features"], dtype=np.float64)
    e = s - np.asarray(obs["features_desired"], dtype=np.float64)
    n = float(np.sqrt(e @ e))
    z = np.asarray(obs["feature_depth"], dtype=np.float64)
    # the desired depth of every corner is the goal tag depth (translation z of tag_pose_desired)
    zd = float(obs["tag_pose_desired"][2])
    return np.concatenate([4.0 * e, e / (n + 0.005), [np.log10(n + 0.001) / 3.0], s, 5.0 * (z - zd),
                           np.asarray(obs["q"], np.float64), 0.5 * np.asarray(obs["dq"], np.float64),
                           np.asarray(obs["visible"], np.float64)]).astype(np.float32)


def servo_pose_vector(obs: dict[str, Any]) -> np.ndarray:
    """Flat float32 vector (52,): :func:`servo_vector`, then the pose error of the tag seen by the camera, from the
    observation's ``tag_pose`` (cMo) and ``tag_pose_desired`` (cdMo): ``10 t``, ``3 theta u`` of
    ``cdMc = cdMo cMo^-1`` (FrankaPBVS-v0's error: zero exactly at the goal pose), and ``log10(||t|| + 0.001) / 3``,
    ``log10(||theta u|| + 0.001) / 3`` (informative at the 5 mm / 0.02 rad of the PBVS tasks' success). Where the
    tag is not seen its pose is zeros, as in the observation; ``visible`` (in the servo vector) says so."""
    from pinocchio import log3

    from franka_vs_gym.model.geometry import inverse_pose, pose_from_vector

    cdMc = pose_from_vector(np.asarray(obs["tag_pose_desired"], np.float64)) @ inverse_pose(
        pose_from_vector(np.asarray(obs["tag_pose"], np.float64)))
    t, w = cdMc[:3, 3], log3(cdMc[:3, :3])
    return np.concatenate([servo_vector(obs), 10.0 * t, 3.0 * w, [np.log10(np.linalg.norm(t) + 0.001) / 3.0,
                                                                   np.log10(np.linalg.norm(w) + 0.001) / 3.0]
                           ]).astype(np.float32)


def layout_vector(layout: str) -> tuple[Any, int]:
    """(the observation function, its size) of a flat layout (OBS_LAYOUT or POSE_LAYOUT)."""
    if layout == OBS_LAYOUT:
        return servo_vector, VECTOR_SIZE
    if layout == POSE_LAYOUT:
        return servo_pose_vector, POSE_VECTOR_SIZE
    raise ValueError(f"observation layout must be {OBS_LAYOUT!r} or {POSE_LAYOUT!r}, got {layout!r}")


class ServoVectorObservation(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Dict contract observation -> the flat vector of :func:`servo_vector` (Box (44,), float32), or with
    ``layout=POSE_LAYOUT`` of :func:`servo_pose_vector` (Box (52,))."""

    def __init__(self, env: gym.Env, layout: str = OBS_LAYOUT) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, layout=layout)
        self._fn, size = layout_vector(layout)
        gym.ObservationWrapper.__init__(self, env)
        needed = {"features", "features_desired", "feature_depth", "tag_pose_desired", "q", "dq", "visible"}
        have = set(getattr(env.observation_space, "spaces", {}))
        if not needed <= have:
            raise ValueError(f"ServoVectorObservation needs the observation keys {sorted(needed)} "
                             f"(observation_type 'features' or 'state'); the env has {sorted(have)}")
        self.observation_space = spaces.Box(-np.inf, np.inf, (size,), dtype=np.float32)

    def observation(self, observation: dict[str, Any]) -> np.ndarray:
        return self._fn(observation)


class ScaledAction(gym.ActionWrapper, gym.utils.RecordConstructorArgs):
    """Actions in [-1, 1]^n mapped linearly to [-scale, scale] in the env's units (e.g. rad/s).

    ``scale`` is a number or an (n,) array; it must lie within the env's action bounds (symmetric Box)."""

    def __init__(self, env: gym.Env, scale: Any) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, scale=scale)
        gym.ActionWrapper.__init__(self, env)
        box = env.action_space
        if not isinstance(box, spaces.Box) or not np.allclose(box.low, -box.high):
            raise ValueError("ScaledAction needs a symmetric Box action space")
        s = np.broadcast_to(np.asarray(scale, dtype=np.float64), box.shape).copy()
        if not np.isfinite(s).all() or (s <= 0).any() or (s > box.high + 1e-6).any():
            raise ValueError(f"scale must be > 0 and within the action bounds {box.high}, got {scale!r}")
        self.scale = s
        self.action_space = spaces.Box(-1.0, 1.0, box.shape, dtype=np.float32)

    def action(self, action: Any) -> np.ndarray:
        a = np.asarray(action, dtype=np.float64)
        if not np.isfinite(a).all():
            raise ValueError(f"action contains NaN or inf: {a}")
        return (np.clip(a, -1.0, 1.0) * self.scale).astype(np.float32)


def make_agent_env(env_id: str = "FrankaIBVS-v0", action_scale: Any = 0.5, observation_layout: str = OBS_LAYOUT,
                   **env_kwargs: Any) -> gym.Env:
    """The training environment of ``baselines/train_sb3.py``: ``env_id`` with features observations and
    joint-velocity actions by default, actions scaled from [-1, 1] to +-``action_scale`` rad/s, flat observation
    (``observation_layout``: the servo vector, or with POSE_LAYOUT the servo vector and the tag's pose error)."""
    import franka_vs_gym  # noqa: F401  (registers the ids)

    env_kwargs.setdefault("observation_type", "features")
    env_kwargs.setdefault("action_type", "joint_velocity")
    env_kwargs.setdefault("action_scale", "physical")  # (ScaledAction does the scaling)
    env = gym.make(env_id, **env_kwargs)
    return ServoVectorObservation(ScaledAction(env, action_scale), observation_layout)


class AgentPolicy:
    """A trained stable-baselines3 agent behind the scripted-policy interface: ``predict(obs) -> action`` with the
    contract observation (dict) in and the physical action (e.g. joint velocities, rad/s) out.

    Load with :meth:`load` from a model zip and its JSON sidecar (same name, ``.json``) written by
    ``baselines/train_sb3.py`` or ``baselines/train_pixels.py``; the sidecar records the env id, env kwargs, action
    scale and observation layout used in training (the flat servo vector, or the camera image with q and dq).
    """

    def __init__(self, model: Any, action_scale: Any, env_id: str = "FrankaIBVS-v0",
                 env_kwargs: dict[str, Any] | None = None, observation_layout: str = OBS_LAYOUT) -> None:
        if observation_layout not in OBS_LAYOUTS:
            raise ValueError(f"observation_layout must be one of {OBS_LAYOUTS}, got {observation_layout!r}")
        self.model = model
        #: what the agent sees: the flat servo vector (OBS_LAYOUT) or the camera image with q and dq (IMAGE_LAYOUT)
        self.observation_layout = observation_layout
        self.training_scale = np.asarray(action_scale, dtype=np.float64)
        #: the physical value of an output of 1 (None: physical outputs, the training scale times the agent's
        #: [-1, 1] action); see with_action_scale
        self.action_scale: np.ndarray | None = None
        self.env_id = env_id
        self.env_kwargs = dict(env_kwargs or {})

    @classmethod
    def load(cls, path: str | os.PathLike) -> AgentPolicy:
        p = Path(path)
        if p.suffix != ".zip":
            p = p.with_suffix(".zip")
        if not p.is_file():
            raise FileNotFoundError(f"agent file not found: {p}")
        meta_path = p.with_suffix(".json")
        if not meta_path.is_file():
            raise FileNotFoundError(f"agent metadata not found: {meta_path} (written next to the zip by "
                                    "baselines/train_sb3.py)")
        meta = json.loads(meta_path.read_text())
        if meta.get("observation_layout") not in OBS_LAYOUTS:
            raise ValueError(f"{meta_path}: observation layout {meta.get('observation_layout')!r} is not one of "
                             f"{OBS_LAYOUTS}")
        import stable_baselines3 as sb3

        algo = getattr(sb3, str(meta.get("algo", "")).upper(), None)
        if algo is None:
            raise ValueError(f"{meta_path}: unknown algorithm {meta.get('algo')!r}")
        model = algo.load(str(p), device="cpu")
        return cls(model, meta["action_scale"], meta.get("env_id", "FrankaIBVS-v0"), meta.get("env_kwargs", {}),
                   meta["observation_layout"])

    def predict(self, observation: dict[str, Any], deterministic: bool = True) -> np.ndarray:
        if self.observation_layout == IMAGE_LAYOUT:
            from franka_vs_gym.envs.pixels import image_observation

            seen: Any = image_observation(observation)
        elif self.observation_layout == POSE_LAYOUT:
            seen = servo_pose_vector(observation)
        else:
            seen = servo_vector(observation)
        a, _ = self.model.predict(seen, deterministic=deterministic)
        phys = np.clip(np.asarray(a, dtype=np.float64), -1.0, 1.0) * self.training_scale
        if self.action_scale is not None:
            phys = phys / self.action_scale
        return phys.astype(np.float32)

    def with_action_scale(self, scale: Any) -> AgentPolicy:
        """A copy whose actions are normalized by ``scale`` (an env's ``action_scale``; None: physical units)."""
        import copy

        out = copy.copy(self)
        out.action_scale = None if scale is None else np.array(scale, dtype=np.float64)
        return out

    def reset(self) -> None:
        """Nothing to forget between episodes (the agent is memoryless)."""
