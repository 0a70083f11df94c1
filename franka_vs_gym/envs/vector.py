"""Many robots in one process: a native Gymnasium vector env whose physics runs on ``mujoco.batch``.

``gymnasium.make_vec("FrankaIBVS-v0", num_envs=N)`` (any registered id) returns a :class:`FrankaVectorEnv`: N
environments of that id, each with its own MuJoCo model (so per-robot randomised masses, payload and friction are
drawn by each environment exactly as a single environment draws them) and its own task logic, whose physics is
stepped together by one ``mujoco.batch.Batch`` on ``nthread`` threads. The batch runs one model for all robots and
holds per robot only the fields where a robot's model differs from it (:class:`BatchModels`: the tag's placement,
randomised masses or friction), so the physics of 64 robots reads one model instead of 64 copies of it. The
plant's friction runs inside MuJoCo's step (the compiled plant, :mod:`franka_vs_gym.sim.plant`), so a control
period is one batched call.

Results are bit for bit those of N single environments (``gymnasium.make``) reset with the same seeds: a batch step
of a simulation loads its state into MuJoCo, runs the same ``mj_step`` calls on the same model and saves the
state back. Where an environment reads the whole scene after its physics (a camera image, rendering), the batch keeps
one MjData per simulation and the scene is copied from it; otherwise one MjData per thread serves all robots (the
physics stays in the cache), and a robot that ends a period in contact runs that period again alone, so that its
environment reads its contacts as a single environment does. The robots' measured-state reflexes run inside
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

import copy as _copy
import os
from collections import defaultdict
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space, create_empty_array

from franka_vs_gym.envs.batched import batched_task
from franka_vs_gym.sim import SimulationDiverged, plant
from franka_vs_gym.sim.reflexes import ControlException
from franka_vs_gym.sim.rendering import SharedRenderers

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
_sum, _all, _any = np.add.reduce, np.logical_and.reduce, np.logical_or.reduce  # (called directly: every step)
# the scene's asset arrays (what a renderer uploads, and the collision structures built from meshes): an
# environment's reset does not edit them (BatchModels compares them only when the models may have been edited)
_ASSET_PREFIXES = ("mesh_", "tex_", "hfield_", "skin_", "flex_", "bvh_", "oct_")
_BAD = [int(mujoco.mjtWarning.mjWARN_BADQPOS), int(mujoco.mjtWarning.mjWARN_BADQVEL),
        int(mujoco.mjtWarning.mjWARN_BADQACC)]
# the same warnings as a slice (a view instead of a fancy-index copy) where MuJoCo numbers them consecutively
_BAD_ROWS = slice(_BAD[0], _BAD[-1] + 1) if _BAD == list(range(_BAD[0], _BAD[-1] + 1)) else _BAD


def make_vector_env(env_id: str, num_envs: int = 1, **kwargs: Any) -> FrankaVectorEnv:
    """The registered ids' ``vector_entry_point``: ``gymnasium.make_vec(env_id, num_envs, **kwargs)``."""
    return FrankaVectorEnv(env_id, num_envs, **kwargs)



class BatchModels:
    """The robots' models in a ``mujoco.batch.Batch``: the batch's one model, with per-robot values (``Batch.expand``)
    of exactly the fields where some robot's model differs from it.

    Each robot's environment owns its model and edits it (a reset draws the tag's placement, randomised masses,
    payload or friction). Before the next batch step, :meth:`sync` compares each edited robot's model with the
    batch's model, gives the fields that differ per-robot values and writes the robot's values into its row (the
    rows of fields already per robot always). A robot thus runs on values equal, bit for bit, to its own model's,
    while the physics of all robots reads one model (64 copies of the model's 1.2 MB do not stay in a core's cache:
    measured 1.20 -> 1.12 x one robot's raw physics for 64 visual-torque robots).

    The comparison is of the models' array memory as a whole: MuJoCo allocates every array of a model in one buffer,
    at the same offsets in models of the same sizes, so one vectorised comparison of the two buffers finds the
    differing words, and the fields holding them follow from the offsets (a field-by-field comparison from Python
    cost about 1.5 ms per reset robot, more than the reset itself). After an environment's own reset the scene's
    assets (meshes, textures and the structures built from them, 97 % of the memory) are left out, as no reset edits
    them: 28 of 926 kB are compared; everything is compared when the vector env is made and after any access to
    ``envs``. ``MjOption``'s fields, which live outside the buffer, are compared one by one.

    Models that differ in a field the batch cannot hold per simulation (meshes, textures, height fields: never
    edited by an environment) make the batch run each robot on its own model (``Batch.set_models``), as before.

    Parameters
    ----------
    batch : the batch (its model: a copy of robot 0's model when it was made).
    models : each robot's model (its environment's, the same objects for the env's life), read at every
        :meth:`sync`.
    """

    def __init__(self, batch: Any, models: list[Any]) -> None:
        from mujoco import batch as mjbatch

        self.batch, self.models = batch, models
        base = batch.model
        fields = sorted(n for n in dir(base) if not n.startswith("_") and isinstance(getattr(base, n), np.ndarray))
        self._fields = fields
        self._expandable = {n for n in fields if n in mjbatch.MODEL_FIELDS}
        self._opt = [(n, n[4:], np.asarray(getattr(base.opt, n[4:])).tobytes())
                     for n in sorted(mjbatch.MODEL_FIELDS) if n.startswith("opt.")]
        self._opts = [m.opt for m in models]  # (each model's MjOption, read in place)
        # each model's arrays as one block of 8-byte words (None: a model whose layout is not the batch model's,
        # compared field by field instead)
        layout = self._layout(base, fields)
        self._bufs: list[np.ndarray | None] = [None] * len(models)
        if layout is not None:
            lo, span, table = layout
            order = np.argsort(table[:, 0], kind="stable")
            used = table[order, 0] >= 0
            order = order[used]
            self._starts, self._ends = table[order, 0], table[order, 0] + table[order, 1]
            self._names = [fields[k] for k in order]
            self._ref = self._words(lo, span).copy()
            # the words compared after an environment's own reset: every field but the scene's assets (meshes,
            # textures, height fields, skins, flexes and the bounding-volume and octree structures built from them),
            # which a reset does not edit; they are compared when the vector env is made and after access to envs
            hot = [np.arange(st // 8, (en + 7) // 8) for st, en, n in zip(self._starts, self._ends, self._names,
                                                                   strict=True) if not n.startswith(_ASSET_PREFIXES)]
            self._hot = np.concatenate(hot) if hot else np.zeros(0, dtype=np.int64)
            self._ref_hot = self._ref[self._hot]
            self._scratch = np.empty_like(self._ref_hot)
            for i, m in enumerate(models):
                ml = self._layout(m, fields)
                if ml is not None and ml[1] == span and np.array_equal(ml[2], table):
                    self._bufs[i] = self._words(ml[0], span)
        self._rows: dict[str, np.ndarray] = {}  # the expanded fields' per-robot values, by field
        #: the robots run on their own models (``Batch.set_models``) instead of the batch's
        self.per_robot = False
        self.pending: set[int] = set()  # robots reset since the last sync (their models' assets are not compared)
        self.pending_all: set[int] = set(range(len(models)))  # robots whose models may have been edited anywhere
        self.sync()

    @staticmethod
    def _layout(m: Any, fields: list[str]) -> tuple[int, int, np.ndarray] | None:
        """(address of the first array, bytes to the end of the last rounded up to 8, (offset or -1 when empty,
        bytes) of each field of ``fields``) of model m's arrays; None unless they lie in one block no larger than
        the model's buffer, each starting on an 8-byte boundary."""
        ptr = np.array([[getattr(m, n).ctypes.data, getattr(m, n).nbytes] for n in fields], dtype=np.int64)
        used = ptr[:, 1] > 0
        lo = int(ptr[used, 0].min())
        span = int((ptr[used, 0] + ptr[used, 1]).max()) - lo
        span += (-span) % 8
        if (ptr[used, 0] % 8).any() or span > int(m.nbuffer):
            return None
        table = ptr.copy()
        table[:, 0] = np.where(used, ptr[:, 0] - lo, -1)
        return lo, span, table

    @staticmethod
    def _words(address: int, span: int) -> np.ndarray:
        """A uint64 view of ``span`` bytes of memory at ``address`` (a model's arrays: the model must outlive it)."""
        import ctypes

        return np.ctypeslib.as_array((ctypes.c_uint64 * (span // 8)).from_address(address))

    @property
    def any_pending(self) -> bool:
        return bool(self.pending or self.pending_all)

    def edited(self, ids: Any = None) -> None:
        """Robots ``ids`` were reset by their environments (their models' assets are not compared), or (None) any
        model may have been edited anywhere: the next :meth:`sync` reads them."""
        if ids is None:
            self.pending_all.update(range(len(self.models)))
        else:
            self.pending.update(int(i) for i in ids)

    def _differing(self, i: int, assets: bool = True) -> set[str]:
        """The fields of robot i's model that differ, bit for bit, from the batch's model (``assets=False``: the
        scene's asset arrays left out)."""
        m, buf, o = self.models[i], self._bufs[i], self._opts[i]
        out = {name for name, f, ref in self._opt if np.asarray(getattr(o, f)).tobytes() != ref}
        if buf is None:
            base = self.batch.model
            return out | {n for n in self._fields if getattr(m, n).tobytes() != getattr(base, n).tobytes()}
        if assets:
            neq = buf != self._ref
            if not _any(neq):
                return out
            words = np.flatnonzero(neq)
        else:
            hot = np.take(buf, self._hot, out=self._scratch)
            neq = hot != self._ref_hot
            if not _any(neq):
                return out
            words = self._hot[np.flatnonzero(neq)]
        # the byte offsets of the differing words, each inside one field (every field starts on a word) or in the
        # padding after one (not a field's value: left out)
        words = words * 8
        k = np.searchsorted(self._starts, words, side="right") - 1
        inside = (k >= 0) & (words < self._ends[np.maximum(k, 0)])
        return out | {self._names[j] for j in np.unique(k[inside])}

    def sync(self) -> None:
        """The edited robots' models into the batch."""
        everywhere, reset = self.pending_all, self.pending - self.pending_all
        self.pending, self.pending_all = set(), set()
        if self.per_robot:
            self.batch.set_models(self.models)  # (the batch reads the caller models; set again after edits)
            return
        rows = self._rows
        diffs = {i: self._differing(i) for i in sorted(everywhere)}
        diffs.update((i, self._differing(i, assets=False)) for i in sorted(reset))
        fixed = sorted({n for d in diffs.values() for n in d if not n.startswith("opt.") and n not in self._expandable})
        if fixed:
            if rows:
                raise RuntimeError(f"a robot's model was edited in a field mujoco.batch cannot hold per simulation "
                                   f"({fixed[0]}) after others were held per robot")
            self.per_robot = True
            self.batch.set_models(self.models)
            return
        for i, diff in diffs.items():
            m = self.models[i]
            for name in diff.union(rows):
                arr = rows.get(name)
                if arr is None:
                    arr = rows[name] = self.batch.expand(name)
                arr[i] = getattr(m.opt, name[4:]) if name.startswith("opt.") else getattr(m, name)

    @property
    def expanded(self) -> list[str]:
        """The fields that hold per-robot values."""
        return sorted(self._rows)


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
    task_logic : bool or None
        Run the tasks' per-step logic once for all robots (``franka_vs_gym.envs.batched``) where the configuration
        allows it (True), or each robot's own Python in turn (False); None (default): from 4 robots on, below which
        the fixed cost of the vectorised calls exceeds the per-robot Python they replace. The results are the same
        bit for bit either way.
    **kwargs :
        The environment's ``gymnasium.make`` keyword arguments (the same for every robot).

    Observations, actions, rewards, ``terminated``/``truncated`` (N,) and ``info`` (Gymnasium's vector layout:
    ``info[key]`` (N,) with the mask ``info["_" + key]``) are those of the single environment, stacked.
    """

    def __init__(self, env_id: str, num_envs: int = 1, *, nthread: int | None = None,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP, copy: bool = True,
                 max_episode_steps: int | None = None, task_logic: bool | None = None, **kwargs: Any) -> None:
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
        self._envs = [env_cls(**kwargs) for _ in range(self.num_envs)]
        e0 = self._envs[0]
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
        self._models = [e.world.model for e in self._envs]
        self._datas = [e.world.data for e in self._envs]
        self._needs_scene = e0.observation_type in ("image", "features+image") or \
            getattr(e0, "feature_source", "ideal") == "detection"
        if task_logic is None:
            task_logic = self.num_envs >= 4
        # persistent (one MjData per simulation): the scene is there to copy after a step, for environments that
        # read it (cameras, rendering). Otherwise one MjData per thread serves all robots, which keeps the physics
        # in the cache (N = 64: 1.20 -> 1.14 x the raw mj_step time for torque tracking, 1.35 -> 1.18 for visual
        # torque), and a robot that ends a period in contact (whose contacts its environment reads) re-runs that
        # period alone, as a single env runs it (_physics; the task logic re-runs it alone anyway).
        self._persistent = self._needs_scene or e0.render_mode is not None
        # (the batch's own model: a private copy of robot 0's, which robot 0's resets then do not edit)
        self.batch = mjbatch.Batch(_copy.copy(self._models[0]), self.num_envs, nthread=self.nthread,
                                   persistent=self._persistent)
        self._batch_models = BatchModels(self.batch, self._models)
        self._state = self.batch.state
        self._ncon = self.batch.bind("ncon")
        self._warning = self.batch.warning
        # cameras: one OpenGL context for all robots (their models share meshes and textures), not one per robot
        self._renderers = SharedRenderers()
        for e in self._envs:
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
        # the task logic over all robots (None: this configuration steps robot by robot around the batched physics)
        self._task = batched_task(self._envs, self.batch) if task_logic and not self._needs_scene and \
            self._flat is not None else None
        self._in_batch = np.zeros(self.num_envs, dtype=np.bool_)  # robot i's state lives in the batch (self._task)
        self._all = np.arange(self.num_envs)  # the robots stepping when none resets (the common case)
        self._all.setflags(write=False)
        self._ones = np.ones(self.num_envs, dtype=np.bool_)  # (an info mask template)
        self._before = np.empty_like(self._state)  # the batch's state before a step of all robots

    @property
    def envs(self) -> list[Any]:
        """The N environments, each holding its robot's current state (robots stepping in the batch are written
        back first)."""
        for i in np.flatnonzero(self._in_batch):
            self._to_env(int(i))
        self._batch_models.edited()  # (the caller may edit a robot's model through its environment)
        return self._envs

    def _to_env(self, i: int) -> None:
        """Robot i's state back into its environment, which then steps it until it is eligible again."""
        if self._in_batch[i]:
            self._task.store(i)
            self._in_batch[i] = False

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
        for i, env in enumerate(self._envs):
            if mask[i]:
                self._to_env(i)
                o, info = env.reset(seed=seeds[i], options=options)
                items.append((i, info))
                obs_list.append((i, o))
                self._autoreset[i] = False
        self._batch_models.edited(np.flatnonzero(mask))  # the resets edited the models (randomised dynamics, ...)
        self._write_obs(obs_list)
        return (self._copy(self._obs), self._batch_infos(items))

    def step(self, actions: Any):
        n = self.num_envs
        actions = np.asarray(actions)
        if actions.shape[:1] != (n,):
            raise ValueError(f"actions must have shape ({n}, ...), got {actions.shape}")
        results: list[Any] = [None] * n
        reset_any = bool(_any(self._autoreset))
        if reset_any:
            # NEXT_STEP: this step resets these environments, ignoring their actions
            for i in np.flatnonzero(self._autoreset):
                i = int(i)
                self._to_env(i)
                o, info = self._envs[i].reset()
                results[i] = (o, 0.0, False, False, info)
            self._batch_models.edited(np.flatnonzero(self._autoreset))
        if self._batch_models.any_pending:
            self._batch_models.sync()
        stepping = np.flatnonzero(~self._autoreset) if reset_any else self._all
        fast = self._fast_rows(stepping) if self._task is not None and len(stepping) else stepping[:0]
        if len(fast) < len(stepping):
            alone = np.setdiff1d(stepping, fast, assume_unique=True)
            self._step_groups([int(i) for i in alone], actions, results)
        cols = self._step_fast(fast, actions, results) if len(fast) else None
        if cols is not None:
            ids, reward, term, trunc, cinfo = cols
            self._rewards[ids], self._terminated[ids], self._truncated[ids] = reward, term, trunc
        per_robot = [] if results.count(None) == n else [i for i in range(n) if results[i] is not None]
        obs_list, items = [], []
        if self.autoreset_mode == AutoresetMode.SAME_STEP and cols is not None:
            ended = ids[term | trunc]
            if len(ended):  # these robots reset now: their last observation and info go into final_obs/final_info
                for i in ended:
                    i = int(i)
                    j = int(np.searchsorted(ids, i))
                    info = {k: (v[j].item() if isinstance(v[j], np.generic) else v[j]) for k, v in cinfo.items()}
                    o = {k: self._flat[i, sl].reshape(shape).copy() for k, sl, shape in self._task.pack_items}
                    results[i] = (o, float(reward[j]), bool(term[j]), bool(trunc[j]), info)
                    per_robot.append(i)
                keep = ~np.isin(ids, ended)
                ids, cinfo = ids[keep], {k: v[keep] for k, v in cinfo.items()}
                per_robot.sort()
        for i in per_robot:
            o, r, term_i, trunc_i, info = results[i]
            if self.autoreset_mode == AutoresetMode.SAME_STEP and (term_i or trunc_i):
                final_obs, final_info = o, info
                self._to_env(i)
                o, info = self._envs[i].reset()
                info = dict(info, final_obs=final_obs, final_info=final_info)
                self._batch_models.edited([i])
            obs_list.append((i, o))
            self._rewards[i], self._terminated[i], self._truncated[i] = r, term_i, trunc_i
            items.append((i, info))
        self._autoreset[:] = (self._terminated | self._truncated) & (self.autoreset_mode == AutoresetMode.NEXT_STEP)
        self._write_obs(obs_list)
        info = self._batch_infos(items, cinfo if cols is not None else None, ids if cols is not None else None)
        return (self._copy(self._obs), self._rewards.copy(), self._terminated.copy(), self._truncated.copy(), info)

    def _fast_rows(self, ids: np.ndarray) -> np.ndarray:
        """The robots of ``ids`` that step in the batch this step: those already there, and those eligible again
        (loaded into it); a robot whose next period is not one physics segment goes back to its environment."""
        task, inb = self._task, self._in_batch
        if len(ids) == self.num_envs and _all(inb):  # all robots, all in the batch already
            ids_out = ids[:0]
        else:
            ids_out = ids[~inb[ids]]
        for i in ids_out:
            i = int(i)
            if task.eligible(self._envs[i]):
                task.load(i)
                inb[i] = True
        fast = ids if not len(ids_out) or _all(inb[ids]) else ids[inb[ids]]
        if hasattr(task, "single_segment") and len(fast):
            single, capture = task.single_segment(fast)
            if not single.all():
                for i in fast[~single]:
                    self._to_env(int(i))
                fast = fast[single]
        return fast

    def _step_fast(self, ids: np.ndarray, actions: np.ndarray, results: list[Any]):
        """One period of the robots ``ids`` (all in the batch): the task's logic for all of them at once around one
        ``Batch.step``. A robot whose step needs anything per robot (a reflex, a divergence, a joint at its stop, a
        contact) is put back where it was before the step and re-runs the step alone in its environment, exactly
        as a single env. Returns (ids stepped here, reward, terminated, truncated, info columns)."""
        task = self._task
        a = task.check_actions(ids, actions)
        capture = task.single_segment(ids)[1] if hasattr(task, "single_segment") else None
        every = len(ids) == self.num_envs  # (ids sorted and unique: all robots, row j is robot j)
        if every:
            before = self._before
            np.copyto(before, task.state)
            rows = slice(None)
        else:
            before = task.state[ids]  # (a copy: fancy indexing)
            rows = ids
        task.command(ids, a)
        warn = self._warning[rows]
        warn0 = _sum(warn[:, _BAD_ROWS, 1], axis=1)
        self.batch.step(None if every else ids.astype(np.int32), nstep=task.n_substeps)
        bad = _sum(warn[:, _BAD_ROWS, 1], axis=1) > warn0 if every else \
            _sum(self._warning[rows][:, _BAD_ROWS, 1], axis=1) > warn0
        bad |= self._ncon[rows] > 0
        bad |= task.anomalies(ids)
        if _any(bad):
            for j in np.flatnonzero(bad):
                i = int(ids[j])
                task.state[i] = before[j]
                self._to_env(i)
                self._envs[i]._step_begin(actions[i])
                results[i] = self._step_alone(i)
            ids = ids[~bad]
            if capture is not None:
                capture = capture[~bad]
        if not len(ids):
            return None
        if capture is None:
            reward, term, trunc, info = task.step_end(ids, self._flat)
        else:
            reward, term, trunc, info = task.step_end(ids, self._flat, capture)
        return ids, reward, term, trunc, info

    def _write_obs(self, obs_list: list[tuple[int, dict[str, np.ndarray]]]) -> None:
        """Observations of robots stepped by their own environment into the preallocated batched observation: one
        row copy per robot when its observation is the environment's packed buffer (every regular step), key by key
        otherwise. (The robots stepped in the batch have their rows written by the task.)"""
        flat, keys = self._flat, self._flat_keys
        for i, o in obs_list:
            pack = getattr(self._envs[i], "_pack", None)
            if flat is not None and pack is not None and pack.last is not None and keys and \
                    o[keys[0]].base is pack.last:
                flat[i] = pack.last
                for k in self._other_keys:
                    self._obs[k][i] = o[k]
            else:
                for k, v in o.items():
                    self._obs[k][i] = v

    def _batch_infos(self, items: list[tuple[int, dict[str, Any]]], columns: dict[str, np.ndarray] | None = None,
                     col_ids: np.ndarray | None = None) -> dict[str, Any]:
        """Gymnasium's vector info layout (as ``VectorEnv._add_info`` builds it, one key at a time instead of one
        environment at a time): ``info[key]`` (N, ...) typed by its first value (in robot order), and the mask
        ``info["_" + key]``. ``items`` are (robot, info) of robots stepped alone, in robot order; ``columns`` the
        info of the robots ``col_ids`` stepped in the batch, one array per key."""
        n = self.num_envs
        if not items and columns is not None and len(col_ids) == n:
            # every robot stepped in the batch (col_ids is 0..N-1): the columns (fresh arrays of the step) are the
            # info arrays VectorEnv would build, all masks set
            out: dict[str, Any] = {}
            for k, col in columns.items():
                out[k] = col
                out["_" + k] = self._ones.copy()
            return out
        by_key: dict[str, list[tuple[int, Any]]] = {}
        for i, info in items:
            for k, v in info.items():
                by_key.setdefault(k, []).append((i, v))
        columns = columns if columns is not None and len(col_ids) else {}
        out = {}
        for k in dict.fromkeys([*columns, *by_key]):
            pairs = by_key.get(k, [])
            col = columns.get(k)
            if col is not None and (not pairs or col_ids[0] < pairs[0][0]):
                arr = np.full(n, None, dtype=object) if col.dtype == object else np.zeros(n, dtype=col.dtype)
            else:
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
            mask = np.zeros(n, dtype=np.bool_)
            if arr is not None:
                for i, v in pairs:
                    arr[i] = v
                if col is not None:
                    arr[col_ids] = col
                out[k] = arr
            mask[[i for i, _ in pairs]] = True
            if col is not None:
                mask[col_ids] = True
            out["_" + k] = mask
        return out

    def _step_groups(self, ids: list[int], actions: np.ndarray, results: list[Any]) -> None:
        """Step the environments ``ids``: actions, physics, observations and rewards. Robots whose period is one
        run of MuJoCo's step (the common case) share one batch call; a robot with Python work between its physics
        steps (brakes holding it after a reflex, rate-limited commands, a command or measurement delay, a camera
        frame in the middle of the period) or already stopped by a reflex steps alone, exactly as a single env."""
        envs = self._envs
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
        env = self._envs[i]
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
        envs, models, datas, state = self._envs, self._models, self._datas, self._state
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
                if bad[i] or (self._ncon[i] and not self._persistent):
                    # diverged, or in contact without the simulation's own data to read the contacts from: the
                    # period runs alone from the state before it, as a single env runs it
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
        for i in range(self.num_envs):  # the scene of each robot's last batch call (its derived quantities too)
            if self._in_batch[i]:
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
        # also called from VectorEnv.__del__ on an instance whose __init__ refused its arguments
        for env in getattr(self, "_envs", ()):
            env.close()
        if hasattr(self, "_renderers"):
            self._renderers.close()


__all__ = ["BatchModels", "FrankaVectorEnv", "make_vector_env"]
