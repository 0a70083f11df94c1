"""Many robots in one process: a native Gymnasium vector env whose physics runs on ``mujoco.batch``.

``gymnasium.make_vec("FrankaIBVS-v0", num_envs=N)`` (any registered id) returns a :class:`FrankaVectorEnv`: N
environments of that id, each with its own MuJoCo model (so per-robot randomised masses, payload and friction are
drawn by each environment exactly as a single environment draws them) and its own task logic, whose physics is
stepped together by one ``mujoco.batch.Batch`` on ``nthread`` threads. The plant's friction runs inside MuJoCo's
step (the compiled plant, :mod:`franka_vs_gym.sim.plant`), so a control period is one batched call.

Results are bit for bit those of N single environments (``gymnasium.make``) reset with the same seeds: a batch step
of a simulation loads its state into MuJoCo, runs the same ``mj_step`` calls on the same model and saves the
state back. Derived quantities an environment reads after its physics (contacts, or the whole scene for a camera
image) are copied from the batch's persistent per-simulation data. The robots' measured-state reflexes run inside
the batch call (the compiled plant checks every physics step and records a violation in the simulation's
``userdata``, part of the state copied back), and the reflex checks run after it as ``SimWorld.step`` runs them,
raising that violation with its time, joint and value. A simulation that diverges is re-run alone by its
environment, which then reports the divergence exactly as a single environment does; so is a robot that needs Python
between its physics steps (brakes holding it after a reflex, rate-limited commands, a command or measurement delay,
a camera frame in the middle of the period).

Autoreset follows Gymnasium 1.x: ``autoreset_mode=AutoresetMode.NEXT_STEP`` (default: the step after an episode
ends resets that environment, ignoring its action) or ``SAME_STEP`` (reset within the step; the last observation
and info are in ``info["final_obs"]`` and ``info["final_info"]``). ``reset(seed=s)`` seeds environment i with
``s + i`` (or ``seed=[s0, s1, ...]``); ``options={"reset_mask": mask}`` resets some of them.
"""

from __future__ import annotations

import os
from collections import defaultdict
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space, create_empty_array

from franka_vs_gym.sim import SimulationDiverged, plant
from franka_vs_gym.sim.reflexes import ControlException
from franka_vs_gym.sim.rendering import SharedRenderers

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
_BAD = [int(mujoco.mjtWarning.mjWARN_BADQPOS), int(mujoco.mjtWarning.mjWARN_BADQVEL),
        int(mujoco.mjtWarning.mjWARN_BADQACC)]


def make_vector_env(env_id: str, num_envs: int = 1, **kwargs: Any) -> FrankaVectorEnv:
    """The registered ids' ``vector_entry_point``: ``gymnasium.make_vec(env_id, num_envs, **kwargs)``."""
    return FrankaVectorEnv(env_id, num_envs, **kwargs)


class FrankaVectorEnv(VectorEnv):
    """N environments of one registered id, their physics stepped together on ``mujoco.batch``.

    Parameters
    ----------
    env_id : str
        A registered id (``franka_vs_gym.envs.ENVS``).
    num_envs : int
        Number of robots N.
    nthread : int or None
        Threads of the batch (None: min(N, CPUs)). The results do not depend on it.
    autoreset_mode : gymnasium.vector.AutoresetMode or str
        NEXT_STEP (default) or SAME_STEP.
    copy : bool
        Return copies of the observation buffers (default True); False returns the same preallocated arrays
        every step, overwritten by the next step.
    **kwargs :
        The environment's ``gymnasium.make`` keyword arguments (the same for every robot).

    Observations, actions, rewards, ``terminated``/``truncated`` (N,) and ``info`` (Gymnasium's vector layout:
    ``info[key]`` (N,) with the mask ``info["_" + key]``) are those of the single environment, stacked.
    """

    def __init__(self, env_id: str, num_envs: int = 1, *, nthread: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, copy: bool = True,
                 max_episode_steps: int | None = None, **kwargs: Any) -> None:
        from mujoco import batch as mjbatch

        from franka_vs_gym.envs.registration import ENVS

        if env_id not in ENVS:
            raise ValueError(f"unknown environment id {env_id!r} (have {list(ENVS)})")
        if not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if max_episode_steps is not None:
            raise ValueError("max_episode_steps is not supported by the batched vector env: use time_limit (s)")
        if not plant.NATIVE:
            raise RuntimeError(f"the batched vector env needs the compiled plant ({plant.unavailable_reason()}); use "
                               "gymnasium.make_vec(..., vectorization_mode='sync') instead")
        self.autoreset_mode = AutoresetMode(autoreset_mode)
        if self.autoreset_mode == AutoresetMode.DISABLED:
            raise ValueError("autoreset_mode must be NEXT_STEP or SAME_STEP")
        self.env_id = env_id
        self.num_envs = int(num_envs)
        entry = gym.spec(env_id).entry_point
        mod, cls = entry.split(":")
        env_cls = getattr(__import__(mod, fromlist=[cls]), cls)
        self.envs = [env_cls(**kwargs) for _ in range(self.num_envs)]
        e0 = self.envs[0]
        self.metadata = dict(e0.metadata, autoreset_mode=self.autoreset_mode)
        self.render_mode = e0.render_mode
        self.spec = None
        self.single_observation_space = e0.observation_space
        self.single_action_space = e0.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.copy = bool(copy)
        self.nthread = min(self.num_envs, os.cpu_count() or 1) if nthread is None else int(nthread)
        if self.nthread < 1:
            raise ValueError(f"nthread must be >= 1, got {nthread}")
        self._models = [e.world.model for e in self.envs]
        self._datas = [e.world.data for e in self.envs]
        # persistent: every simulation keeps its MjData, so contacts and the scene are there to copy after a step
        self.batch = mjbatch.Batch(self._models[0], self.num_envs, nthread=self.nthread, persistent=True)
        self.batch.set_models(self._models)
        self._state = self.batch.state
        self._ncon = self.batch.bind("ncon")
        self._warning = self.batch.warning
        self._needs_scene = e0.observation_type in ("image", "features+image") or \
            getattr(e0, "feature_source", "ideal") == "detection"
        # cameras: one OpenGL context for all robots (their models share meshes and textures), not one per robot
        self._renderers = SharedRenderers()
        for e in self.envs:
            e.world.share_renderers(self._renderers)
        self._obs = create_empty_array(self.single_observation_space, self.num_envs)
        # the packed (float32) keys as views of one (N, size) matrix, written one row per robot
        pack = getattr(e0, "_pack", None)
        self._flat = None
        self._flat_keys: list[str] = []
        self._other_keys = [k for k in self.single_observation_space.spaces]
        if pack is not None and all(self.single_observation_space[k].dtype == np.float32 for k in pack.keys):
            size = sum(sl.stop - sl.start for _, sl, _ in pack.items)
            self._flat = np.zeros((self.num_envs, size), dtype=np.float32)
            for k, sl, shape in pack.items:
                self._obs[k] = self._flat[:, sl].reshape(self.num_envs, *shape)
            self._flat_keys = list(pack.keys)
            self._other_keys = [k for k in self._other_keys if k not in pack.keys]
        self._rewards = np.zeros(self.num_envs)
        self._terminated = np.zeros(self.num_envs, dtype=np.bool_)
        self._truncated = np.zeros(self.num_envs, dtype=np.bool_)
        self._autoreset = np.zeros(self.num_envs, dtype=np.bool_)

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None):
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(f"seed must be an int or a list of {n} seeds, got {len(seeds)}")
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        mask = np.ones(n, dtype=np.bool_) if mask is None else np.asarray(mask, dtype=np.bool_)
        if mask.shape != (n,):
            raise ValueError(f"reset_mask must have shape ({n},), got {mask.shape}")
        items = []
        obs_list = []
        for i, env in enumerate(self.envs):
            if mask[i]:
                o, info = env.reset(seed=seeds[i], options=options)
                items.append((i, info))
                self._autoreset[i] = False
            else:
                o = env._last_obs
            obs_list.append(o)
        self.batch.set_models(self._models)  # the resets edited the models (randomised dynamics, control gains)
        self._write_obs(obs_list)
        return (self._copy(self._obs), self._batch_infos(items))

    def step(self, actions: Any):
        n = self.num_envs
        actions = np.asarray(actions)
        if actions.shape[:1] != (n,):
            raise ValueError(f"actions must have shape ({n}, ...), got {actions.shape}")
        results: list[Any] = [None] * n
        stepping = []
        reset_any = False
        for i, env in enumerate(self.envs):
            if self._autoreset[i]:  # NEXT_STEP: this step resets the environment, ignoring its action
                o, info = env.reset()
                results[i] = (o, 0.0, False, False, info)
                reset_any = True
            else:
                stepping.append(i)
        if reset_any:
            self.batch.set_models(self._models)
        if stepping:
            self._step_groups(stepping, actions, results)
        obs_list, items = [], []
        for i in range(n):
            o, r, term, trunc, info = results[i]
            if self.autoreset_mode == AutoresetMode.SAME_STEP and (term or trunc):
                final_obs, final_info = o, info
                o, info = self.envs[i].reset()
                info = dict(info, final_obs=final_obs, final_info=final_info)
                reset_any = True
            obs_list.append(o)
            self._rewards[i], self._terminated[i], self._truncated[i] = r, term, trunc
            items.append((i, info))
        if reset_any and self.autoreset_mode == AutoresetMode.SAME_STEP:
            self.batch.set_models(self._models)
        self._autoreset[:] = (self._terminated | self._truncated) & (self.autoreset_mode == AutoresetMode.NEXT_STEP)
        self._write_obs(obs_list)
        return (self._copy(self._obs), self._rewards.copy(), self._terminated.copy(), self._truncated.copy(),
                self._batch_infos(items))

    def _write_obs(self, obs_list: list[dict[str, np.ndarray]]) -> None:
        """The robots' observations into the preallocated batched observation: one row copy per robot when its
        observation is the environment's packed buffer (every regular step), key by key otherwise."""
        flat, keys = self._flat, self._flat_keys
        for i, (o, env) in enumerate(zip(obs_list, self.envs, strict=True)):
            pack = getattr(env, "_pack", None)
            if flat is not None and pack is not None and pack.last is not None and keys and \
                    o[keys[0]].base is pack.last:
                flat[i] = pack.last
                for k in self._other_keys:
                    self._obs[k][i] = o[k]
            else:
                for k, v in o.items():
                    self._obs[k][i] = v

    def _batch_infos(self, items: list[tuple[int, dict[str, Any]]]) -> dict[str, Any]:
        """Gymnasium's vector info layout (as ``VectorEnv._add_info`` builds it, one key at a time instead of one
        environment at a time): ``info[key]`` (N, ...) typed by its first value, and the mask ``info["_" + key]``."""
        n = self.num_envs
        by_key: dict[str, list[tuple[int, Any]]] = {}
        for i, info in items:
            for k, v in info.items():
                by_key.setdefault(k, []).append((i, v))
        out: dict[str, Any] = {}
        for k, pairs in by_key.items():
            first = pairs[0][1]
            if k == "final_obs":
                arr = np.full(n, None, dtype=object)
            elif isinstance(first, dict):
                out[k] = self._batch_infos(pairs)
                arr = None
            elif type(first) in (int, float, bool) or isinstance(first, np.number):
                arr = np.zeros(n, dtype=type(first))
            elif isinstance(first, np.ndarray):
                arr = np.zeros((n, *first.shape), dtype=first.dtype)
            else:
                arr = np.full(n, None, dtype=object)
            idx = [i for i, _ in pairs]
            if arr is not None:
                for i, v in pairs:
                    arr[i] = v
                out[k] = arr
            mask = np.zeros(n, dtype=np.bool_)
            mask[idx] = True
            out["_" + k] = mask
        return out

    def _step_groups(self, ids: list[int], actions: np.ndarray, results: list[Any]) -> None:
        """Step the environments ``ids``: actions, physics, observations and rewards. Robots whose period is one
        run of MuJoCo's step (the common case) share one batch call; a robot with Python work between its physics
        steps (brakes holding it after a reflex, rate-limited commands, a command or measurement delay, a camera
        frame in the middle of the period) or already stopped by a reflex steps alone, exactly as a single env."""
        envs = self.envs
        batched = []
        for i in ids:
            env = envs[i]
            env._step_begin(actions[i])
            w = env.world
            if env._reflex is None and not w._active and not w._post_hooks and len(env._segments()) == 1:
                batched.append(i)
            else:
                results[i] = self._step_alone(i)
        if batched:
            self._physics(batched, results)

    def _step_alone(self, i: int):
        """The rest of a single env's ``step`` after ``_step_begin`` (its own physics)."""
        env = self.envs[i]
        try:
            if env._reflex is None:
                env._advance()
        except SimulationDiverged as e:
            return env._step_diverged(e)
        except ControlException as e:
            env._reflex = e
        return env._step_end()

    def _physics(self, ids: list[int], results: list[Any]) -> None:
        """One control period of the environments ``ids`` (one physics segment each) in one batch call, then what
        ``SimWorld.step`` does after its physics (divergence, the robots' reflex checks) and the step results."""
        envs, models, datas, state = self.envs, self._models, self._datas, self._state
        for i in ids:
            mujoco.mj_getState(models[i], datas[i], state[i], _STATE)
        before = state.copy()
        warn0 = self._warning[:, _BAD, 1].sum(axis=1)
        groups: dict[tuple[int, bool], list[int]] = defaultdict(list)
        for i in ids:
            groups[envs[i]._segments()[0]].append(i)
        for (nstep, _), group in groups.items():
            self.batch.step(None if len(group) == self.num_envs else np.array(group, dtype=np.int32), nstep=nstep)
        bad = self._warning[:, _BAD, 1].sum(axis=1) > warn0
        for (nstep, capture), group in groups.items():
            for i in group:
                env = envs[i]
                if bad[i]:  # diverged: run the period alone from the state before it, as a single env does
                    mujoco.mj_setState(models[i], datas[i], before[i], _STATE)
                    results[i] = self._step_alone(i)
                    continue
                self._sync(i)
                try:
                    for check in env.world._checks:  # as SimWorld.step after its physics (reflexes)
                        check()
                    env._segment_done(nstep, capture)
                except SimulationDiverged as e:
                    results[i] = env._step_diverged(e)
                    continue
                except ControlException as e:
                    env._reflex = e
                results[i] = env._step_end()

    def _sync(self, i: int) -> None:
        """Simulation i's state (and, when the environment reads them, its contacts or whole scene) into its
        environment's MjData."""
        if self._needs_scene or self._ncon[i]:
            self.batch.get_data(i, self._datas[i])
        else:
            mujoco.mj_setState(self._models[i], self._datas[i], self._state[i], _STATE)

    def _copy(self, obs: Any) -> Any:
        if not self.copy:
            return obs
        return {k: v.copy() for k, v in obs.items()} if isinstance(obs, dict) else obs.copy()

    def render(self) -> tuple[Any, ...] | None:
        """Each environment's ``render()`` (``render_mode="rgb_array"``), as a tuple."""
        if self.render_mode is None:
            return None
        for i in range(self.num_envs):
            self.batch.get_data(i, self._datas[i])
        return tuple(env.render() for env in self.envs)

    def call(self, name: str, *args: Any, **kwargs: Any) -> tuple[Any, ...]:
        """Call a method (or read an attribute) of every environment."""
        out = []
        for env in self.envs:
            f = getattr(env, name)
            out.append(f(*args, **kwargs) if callable(f) else f)
        return tuple(out)

    def get_attr(self, name: str) -> tuple[Any, ...]:
        return tuple(getattr(env, name) for env in self.envs)

    def set_attr(self, name: str, values: Any) -> None:
        if not isinstance(values, (list, tuple)):
            values = [values] * self.num_envs
        for env, v in zip(self.envs, values, strict=True):
            setattr(env, name, v)

    def close_extras(self, **kwargs: Any) -> None:
        for env in self.envs:
            env.close()
        self._renderers.close()


__all__ = ["FrankaVectorEnv", "make_vector_env"]
