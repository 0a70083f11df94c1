"""Residual torque agents for the torque-action environments (FrankaTorqueTracking-v0, FrankaVisualTorque-v0).

Raw joint-effort actions train poorly (the issue's PPO run: 0 of 10 episodes); residual torques on top of a fixed,
model-based controller, scaled and clipped, with normalised observations, learn. This module is that structure,
shared by the training wrapper (:class:`ResidualTorqueEnv`), the shipped agent (:class:`TorqueAgentPolicy`, what
``franka_vs_gym.evaluate`` and the pylibfranka runner ``franka_vs_gym.fci.deploy`` play) and the recipe
(``baselines/train_torque.py``). What is fixed and what is learnt:

- **fixed** (:class:`ResidualBase`): a gravity-free torque computed from the env's own observation with the
  agent's plant model (the ``model`` the agent was trained on: the default, a calibrated model file, ...);
  - FrankaTorqueTracking-v0: computed torque (``franka_vs_gym.policies.ComputedTorquePolicy``, its defaults:
    ``M(q) (ddq_d + Kp e + Kd de) + C(q, dq) dq + F(dq)``, smooth start);
  - FrankaVisualTorque-v0: the scripted IBVS law's joint velocities (``IBVSPolicy``) tracked by a joint velocity
    loop, ``M(q) Kv (dq_ibvs - dq) + C(q, dq) dq + F(dq)`` with ``Kv`` = 30 1/s;
- **learnt** (the network, an MLP on a normalised flat observation): a residual torque ``r in [-1, 1]^7`` times
  ``residual_fraction`` (:data:`RESIDUAL_FRACTION` = 2) times the env's own torque action scale
  (``env.unwrapped.default_action_scale("torque")``; FER tracking 3.5, 7.3, 5.0, 5.9, 0.90, 0.85, 0.34 Nm, so a
  residual of up to 7.0, 14.6, 9.9, 11.9, 1.8, 1.7, 0.7 Nm: enough to hold a 1.5 kg undeclared payload), added to
  the base; the sum is clipped to the robot's torque limits and is the env's physical torque action.

The network starts as a zero residual (SB3's small final layer), so training starts from the base's behaviour and
learns what the base's model gets wrong on the plant it is trained on (e.g. under dynamics randomisation).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

#: observation layouts of the residual torque agents (the AgentPolicy sidecar's ``observation_layout``)
TRACKING_LAYOUT = "tracking-residual/1"
VISUAL_LAYOUT = "visual-torque-residual/1"
LAYOUTS = {"FrankaTorqueTracking-v0": TRACKING_LAYOUT, "FrankaVisualTorque-v0": VISUAL_LAYOUT}
RESIDUAL_FRACTION = 2.0
VELOCITY_GAIN = 30.0  # 1/s, FrankaVisualTorque-v0's base joint velocity loop
TRACKING_SIZE = 42


def tracking_vector(obs: dict[str, Any]) -> np.ndarray:
    """Flat float32 (42,) of a FrankaTorqueTracking-v0 observation: ``10 (q_d - q)``, ``2 (dq_d - dq)``, ``q``,
    ``0.5 dq``, ``0.5 dq_d``, ``0.1 ddq_d`` (each part about unit size over the task's range)."""
    g = {k: np.asarray(obs[k], dtype=np.float64).reshape(-1) for k in ("q", "dq", "q_desired", "dq_desired",
                                                                     "ddq_desired")}
    return np.concatenate([10.0 * (g["q_desired"] - g["q"]), 2.0 * (g["dq_desired"] - g["dq"]), g["q"],
                           0.5 * g["dq"], 0.5 * g["dq_desired"], 0.1 * g["ddq_desired"]]).astype(np.float32)


def agent_vector(layout: str, obs: dict[str, Any]) -> np.ndarray:
    """The network's input for ``layout`` from the env's dict observation."""
    if layout == TRACKING_LAYOUT:
        return tracking_vector(obs)
    if layout == VISUAL_LAYOUT:
        from franka_vs_gym.envs.wrappers import servo_vector

        return servo_vector(obs)
    raise ValueError(f"observation layout must be one of {sorted(set(LAYOUTS.values()))}, got {layout!r}")


def _model(model: Any, robot: Any) -> Any:
    from franka_vs_gym.policies.torque import _as_model

    return _as_model(model, robot)


class ResidualBase:
    """The fixed part of a residual torque agent: the base torque (7,) Nm, gravity-free, from one dict observation
    (see the module docstring), and the residual's scale (7,) Nm.

    ``env_id``: FrankaTorqueTracking-v0 or FrankaVisualTorque-v0; ``model``: the agent's plant model (None: the
    robot's default; a model file; a ModelConfig; a FrankaModel); ``robot``: "fer" or "fr3"; ``residual_scale``:
    (7,) Nm (default :data:`RESIDUAL_FRACTION` of the env's torque action scale on that model)."""

    def __init__(self, env_id: str, model: Any = None, robot: Any = None, residual_scale: Any = None,
                 env_kwargs: dict[str, Any] | None = None, residual_fraction: float = RESIDUAL_FRACTION) -> None:
        if env_id not in LAYOUTS:
            raise ValueError(f"residual torque agents exist for {sorted(LAYOUTS)}, got {env_id!r}")
        self.env_id, self.layout = env_id, LAYOUTS[env_id]
        self.model = _model(model, robot)
        self.tau_max = self.model.limits()["tau_max"]
        if env_id == "FrankaTorqueTracking-v0":
            from franka_vs_gym.policies import ComputedTorquePolicy

            self._ct = ComputedTorquePolicy(self.model, clip=False)
        else:
            from franka_vs_gym.policies import IBVSPolicy

            self._ibvs = IBVSPolicy(model=self.model)
        if residual_scale is None:
            residual_scale = float(residual_fraction) * default_torque_scale(env_id, self.model, env_kwargs or {})
        self.residual_scale = np.asarray(residual_scale, dtype=np.float64).reshape(7)

    def reset(self) -> None:
        if self.env_id == "FrankaTorqueTracking-v0":
            self._ct.reset()

    def torque(self, obs: dict[str, Any]) -> np.ndarray:
        """The base torque (7,) Nm, gravity-free, for one dict observation."""
        if self.env_id == "FrankaTorqueTracking-v0":
            return np.asarray(self._ct.predict(obs)[0], dtype=np.float64)
        dq_ref = np.asarray(self._ibvs.predict(obs)[0], dtype=np.float64)
        q = np.asarray(obs["q"], dtype=np.float64)
        dq = np.asarray(obs["dq"], dtype=np.float64)
        m = self.model
        return m.mass_matrix(q) @ (VELOCITY_GAIN * (dq_ref - dq)) + m.coriolis(q, dq) + m.friction(dq)

    def combine(self, base: np.ndarray, residual: Any) -> np.ndarray:
        """base + residual_scale * clip(residual, -1, 1), clipped to the torque limits (Nm)."""
        r = np.asarray(residual, dtype=np.float64).reshape(7)
        if not np.isfinite(r).all():
            raise ValueError(f"residual action contains NaN or inf: {r}")
        return np.clip(base + self.residual_scale * np.clip(r, -1.0, 1.0), -self.tau_max, self.tau_max)


def default_torque_scale(env_id: str, model: Any, env_kwargs: dict[str, Any]) -> np.ndarray:
    """The env's default torque action scale (Nm, (7,)) for ``model`` (a FrankaModel): the tracking task's
    motion-based scale, or the base env's (0.5 rad/s^2, 0.5 rad/s)."""
    from franka_vs_gym.envs.base import torque_action_scale

    if env_id == "FrankaTorqueTracking-v0":
        amp = float(env_kwargs.get("amplitude", 0.3))
        f_hi = float(np.asarray(env_kwargs.get("frequency_range", (0.2, 0.5)), dtype=np.float64)[1])
        w = 2 * np.pi * f_hi
        return torque_action_scale(model, amp * w * w, amp * w)
    return torque_action_scale(model, 0.5, 0.5)


class ResidualTorqueEnv(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Training wrapper: actions in [-1, 1]^7 are the residual (see :class:`ResidualBase`); the wrapped env
    (torque actions, ``action_scale="physical"``) receives base + residual; observations are the flat vector of the
    env's layout. The base is built on the env's own model (``env.unwrapped.config``), as the shipped agent's."""

    def __init__(self, env: gym.Env, residual_fraction: float = RESIDUAL_FRACTION) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, residual_fraction=residual_fraction)
        gym.Wrapper.__init__(self, env)
        u = env.unwrapped
        if u.action_type != "torque" or u.action_scale is not None:
            raise ValueError("ResidualTorqueEnv needs an env with action_type='torque' and action_scale='physical'")
        env_id = env.spec.id if env.spec is not None else type(u).__name__
        self.base = ResidualBase(env_id, u.config, residual_fraction=residual_fraction)
        self.action_space = spaces.Box(-1.0, 1.0, (7,), dtype=np.float32)
        n = TRACKING_SIZE if self.base.layout == TRACKING_LAYOUT else 44
        self.observation_space = spaces.Box(-np.inf, np.inf, (n,), dtype=np.float32)
        self._obs: dict[str, Any] | None = None

    def reset(self, **kwargs: Any):
        obs, info = self.env.reset(**kwargs)
        self.base.reset()
        self._obs = obs
        return agent_vector(self.base.layout, obs), info

    def step(self, action: Any):
        tau = self.base.combine(self.base.torque(self._obs), action)
        obs, reward, term, trunc, info = self.env.step(tau.astype(np.float32))
        self._obs = obs
        return agent_vector(self.base.layout, obs), reward, term, trunc, info


def make_residual_env(env_id: str, **env_kwargs: Any) -> gym.Env:
    """``env_id`` with torque actions in Nm wrapped in :class:`ResidualTorqueEnv` (the training env)."""
    import franka_vs_gym  # noqa: F401  (registers the ids)

    env_kwargs = dict(env_kwargs, action_type="torque", action_scale="physical")
    env_kwargs.setdefault("clip_actions", True)
    return ResidualTorqueEnv(gym.make(env_id, **env_kwargs))


class TorqueAgentPolicy:
    """A trained residual torque agent behind the scripted-policy interface: ``predict(obs) -> (action, None)``
    with the env's dict observation in and the physical gravity-free torque (Nm, (7,) float32) out: the base of the
    agent's model plus the network's residual. Load with :meth:`load` (zip + JSON sidecar of
    ``baselines/train_torque.py``)."""

    def __init__(self, model: Any, env_id: str, robot: str = "fer", plant_model: Any = None,
                 env_kwargs: dict[str, Any] | None = None, residual_fraction: float = RESIDUAL_FRACTION) -> None:
        self.model = model
        self.env_id, self.robot = env_id, robot
        self.env_kwargs = dict(env_kwargs or {})
        self.base = ResidualBase(env_id, plant_model, robot, env_kwargs=self.env_kwargs,
                                 residual_fraction=residual_fraction)
        self.observation_layout = self.base.layout
        self.action_scale: np.ndarray | None = None  # physical outputs (Nm); see with_action_scale

    @classmethod
    def load(cls, path: str | os.PathLike, plant_model: Any = "sidecar", robot: str | None = None
             ) -> TorqueAgentPolicy:
        """The agent of a zip and its sidecar; ``plant_model``: the model its base uses ("sidecar": the one it was
        trained on, as the sidecar's ``env_kwargs["model"]`` names it; None: the robot's default); ``robot``: the
        robot it is played on (default the sidecar's; another robot takes that robot's default model)."""
        p = Path(path)
        if p.suffix != ".zip":
            p = p.with_suffix(".zip")
        meta_path = p.with_suffix(".json")
        if not p.is_file() or not meta_path.is_file():
            raise FileNotFoundError(f"agent not found: {p} and its sidecar {meta_path}")
        meta = json.loads(meta_path.read_text())
        if meta.get("observation_layout") not in LAYOUTS.values():
            raise ValueError(f"{meta_path}: observation layout {meta.get('observation_layout')!r} is not a residual "
                             f"torque agent's ({sorted(set(LAYOUTS.values()))})")
        import stable_baselines3 as sb3

        algo = getattr(sb3, str(meta.get("algo", "")).upper(), None)
        if algo is None:
            raise ValueError(f"{meta_path}: unknown algorithm {meta.get('algo')!r}")
        kw = dict(meta.get("env_kwargs", {}))
        if plant_model == "sidecar":
            plant_model = kw.get("model")
        own = meta.get("robot", "fer")
        if robot is not None and robot != own:
            plant_model = None
            kw.pop("model", None)
        return cls(algo.load(str(p), device="cpu"), meta["env_id"], robot or own, plant_model, kw,
                   float(meta.get("residual_fraction", RESIDUAL_FRACTION)))

    @property
    def env_defaults(self) -> dict[str, Any]:
        """The env keywords this agent is played with (``franka-vs evaluate`` takes them; the sidecar's
        ``env_kwargs`` and the command line's come on top): physical torque actions, clipped, on its robot."""
        return {"action_type": "torque", "action_scale": "physical", "clip_actions": True, "robot": self.robot}

    def reset(self) -> None:
        self.base.reset()

    def predict(self, observation: dict[str, Any], state: Any = None, episode_start: Any = None,
                deterministic: bool = True) -> tuple[np.ndarray, None]:
        if episode_start is not None and bool(np.any(episode_start)):
            self.reset()
        base = self.base.torque(observation)
        a, _ = self.model.predict(agent_vector(self.observation_layout, observation), deterministic=deterministic)
        tau = self.base.combine(base, a)
        if self.action_scale is not None:
            tau = tau / self.action_scale
        return tau.astype(np.float32), None

    def with_action_scale(self, scale: Any) -> TorqueAgentPolicy:
        """A copy whose actions are normalized by ``scale`` (an env's ``action_scale``; None: Nm)."""
        import copy

        out = copy.copy(self)
        out.action_scale = None if scale is None else np.array(scale, dtype=np.float64)
        return out


__all__ = ["LAYOUTS", "RESIDUAL_FRACTION", "TRACKING_LAYOUT", "VISUAL_LAYOUT", "ResidualBase", "ResidualTorqueEnv",
           "TorqueAgentPolicy", "agent_vector", "make_residual_env", "tracking_vector"]
