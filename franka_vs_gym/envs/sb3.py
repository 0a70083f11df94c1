"""stable-baselines3 on the batched vector env: a ``VecEnv`` over :class:`~franka_vs_gym.envs.vector.FrankaVectorEnv`.

SB3 resets an environment within the step that ends its episode and hands the last observation over in
``info["terminal_observation"]``; the batched vector env does that in its SAME_STEP autoreset mode, which this
adapter uses. Optional per-robot transforms turn the contract observation and the agent's action into what the
policy sees (the training wrappers of :mod:`franka_vs_gym.envs.wrappers`, applied without a Python env per robot).
Needs the ``[rl]`` extra.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from franka_vs_gym.envs.vector import FrankaVectorEnv


class SB3VecEnv(VecEnv):
    """A stable-baselines3 ``VecEnv`` stepping N robots on ``mujoco.batch``.

    Parameters
    ----------
    venv : FrankaVectorEnv
        Made with ``autoreset_mode="SameStep"`` (the adapter checks).
    obs_fn : callable or None
        Maps one robot's contract observation (dict) to what the policy sees; None keeps the dict.
    observation_space : gymnasium Space or None
        The space of ``obs_fn``'s output (required with ``obs_fn``).
    action_fn : callable or None
        Maps the policy's (N, ...) actions to the environments' physical (N, ...) actions; None passes them on.
    action_space : gymnasium Space or None
        The policy's action space for one robot (required with ``action_fn``).
    """

    def __init__(self, venv: FrankaVectorEnv, obs_fn: Callable[[dict[str, Any]], Any] | None = None,
                 observation_space: spaces.Space | None = None,
                 action_fn: Callable[[np.ndarray], np.ndarray] | None = None,
                 action_space: spaces.Space | None = None) -> None:
        if venv.autoreset_mode.value != "SameStep":
            raise ValueError("SB3VecEnv needs the vector env in autoreset_mode='SameStep'")
        if (obs_fn is None) != (observation_space is None) or (action_fn is None) != (action_space is None):
            raise ValueError("give obs_fn with observation_space and action_fn with action_space")
        self.venv = venv
        self.obs_fn, self.action_fn = obs_fn, action_fn
        super().__init__(venv.num_envs, observation_space or venv.single_observation_space,
                         action_space or venv.single_action_space)
        self._actions: np.ndarray | None = None

    def _obs(self, obs: dict[str, np.ndarray]) -> Any:
        if self.obs_fn is None:
            return obs
        return np.stack([self.obs_fn({k: v[i] for k, v in obs.items()}) for i in range(self.num_envs)])

    def reset(self):
        seeds = [None if s is None else int(s) for s in self._seeds]
        obs, info = self.venv.reset(seed=seeds if any(s is not None for s in seeds) else None)
        self.reset_infos = [{k: v[i] for k, v in info.items() if not k.startswith("_") and info["_" + k][i]}
                            for i in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return self._obs(obs)

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        a = self._actions if self.action_fn is None else self.action_fn(self._actions)
        obs, rew, term, trunc, info = self.venv.step(a)
        dones = term | trunc
        infos: list[dict[str, Any]] = []
        for i in range(self.num_envs):
            d = {k: v[i] for k, v in info.items()
                 if not k.startswith("_") and k not in ("final_obs", "final_info") and info["_" + k][i]}
            if dones[i]:
                final = info["final_info"]
                d = {k: v[i] for k, v in final.items() if not k.startswith("_") and final["_" + k][i]}
                last = info["final_obs"][i]
                d["terminal_observation"] = last if self.obs_fn is None else self.obs_fn(last)
                self.reset_infos[i] = {}
            d["TimeLimit.truncated"] = bool(trunc[i] and not term[i])
            infos.append(d)
        return self._obs(obs), rew.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    def _indices(self, indices: Any) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        if isinstance(indices, int):
            return [indices]
        return list(indices)

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        return [getattr(self.venv.envs[i], attr_name) for i in self._indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        for i in self._indices(indices):
            setattr(self.venv.envs[i], attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **method_kwargs: Any) -> list[Any]:
        return [getattr(self.venv.envs[i], method_name)(*method_args, **method_kwargs)
                for i in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False for _ in self._indices(indices)]


def make_agent_vec_env(env_id: str, num_envs: int, action_scale: Any = 0.5, nthread: int | None = None,
                       observation_layout: str | None = None, **env_kwargs: Any) -> SB3VecEnv:
    """The training environment of ``baselines/train_sb3.py --batched``: :func:`~franka_vs_gym.envs.wrappers.
    make_agent_env`'s observation (the flat servo vector; ``observation_layout`` POSE_LAYOUT: with the tag's pose
    error) and action scaling ([-1, 1] to +-``action_scale`` rad/s), for ``num_envs`` robots on one batch."""
    from franka_vs_gym.envs.wrappers import OBS_LAYOUT, layout_vector

    obs_fn, size = layout_vector(observation_layout or OBS_LAYOUT)

    env_kwargs.setdefault("observation_type", "features")
    env_kwargs.setdefault("action_type", "joint_velocity")
    env_kwargs.setdefault("action_scale", "physical")  # (action_fn does the scaling)
    venv = FrankaVectorEnv(env_id, num_envs, nthread=nthread, autoreset_mode="SameStep", **env_kwargs)
    box = venv.single_action_space
    scale = np.broadcast_to(np.asarray(action_scale, dtype=np.float64), box.shape).copy()
    if not np.isfinite(scale).all() or (scale <= 0).any() or (scale > box.high + 1e-6).any():
        raise ValueError(f"action_scale must be > 0 and within the action bounds {box.high}, got {action_scale!r}")

    def action_fn(a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        if not np.isfinite(a).all():
            raise ValueError("actions contain NaN or inf")
        return (np.clip(a, -1.0, 1.0) * scale).astype(np.float32)

    return SB3VecEnv(venv, obs_fn, spaces.Box(-np.inf, np.inf, (size,), dtype=np.float32),
                     action_fn, spaces.Box(-1.0, 1.0, box.shape, dtype=np.float32))


__all__ = ["SB3VecEnv", "make_agent_vec_env"]
