"""The per-step task logic of N robots at once, for the batched vector env (:mod:`franka_vs_gym.envs.vector`).

While a robot steps in the batch its state lives in the batch: its MuJoCo state in the row of ``mujoco.batch``'s
state (read and written through ``Batch.bind`` views, (N, ...)), its task state (step count, episode start, desired
trajectory, held camera frame, ...) in the (N, ...) arrays of a :class:`BatchedTask`. A step is then a handful of
numpy calls for all robots: the actions checked and written into the batch's controls, one ``Batch.step``, the
reflex and divergence checks, the observations packed into one preallocated (N, size) matrix, rewards,
terminations and the info columns. The formulas are those of the single environments
(:mod:`franka_vs_gym.envs.kernels`, with the compiled kernels of ``franka_vs_gym/sim/_task.c`` for the visual tasks'
ground truth and torque tracking's step end), which call them with N = 1.

A robot goes back to its own environment object (:meth:`BatchedTask.store`: its MuJoCo state into its MjData, its
task state into its attributes) whenever something per robot happens: a reset, a step whose physics needs Python
between physics steps, a tripped reflex, a divergence, a contact or joint-limit failure (the step is then re-run by
the robot's own environment from the state before it, exactly as a single env runs it), a camera frame in the
middle of a period, or any access to ``FrankaVectorEnv.envs``. :meth:`BatchedTask.load` brings it back.

Which configurations step here (:meth:`BatchedTask.supports`): the registered tasks with joint-torque or
joint-velocity actions, feature or state observations from the ideal projection (observation noise is drawn
robot by robot from each environment's generator, in a single env's order), the compiled plant with its reflexes
armed, no command delay and libfranka's command rates passed through ("pass"). Every other configuration steps
robot by robot around the batched physics, as before.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from franka_vs_gym.envs.kernels import (
    R_CMO,
    R_DEPTH,
    R_ERROR,
    R_FEATURES,
    R_POSE,
    R_VISIBLE,
    REC,
    TAG_LOST,
    clip_observation,
    feature_reward,
    pbvs_errors,
    pose_reward,
    success_bonus,
    torque_penalty,
    truth_records,
)
from franka_vs_gym.envs.torque_tracking import tracking_lost
from franka_vs_gym.sim import FORCE_TORQUE, VELOCITY, plant
from franka_vs_gym.sim.reflexes import ARMED
from franka_vs_gym.sim.robot import VELOCITY_COMMAND_SCALE
from franka_vs_gym.vision.tags import project_tag

_STATE = mujoco.mjtState.mjSTATE_INTEGRATION
_all, _any = np.logical_and.reduce, np.logical_or.reduce  # (the reductions called directly: every step)


class BatchedTask:
    """The common part (actions, commands, reflex checks, joint state, failures, info) of N robots of one task.

    Parameters
    ----------
    envs : the N environments (same class and configuration).
    batch : their ``mujoco.batch.Batch`` (persistent).

    Arrays (N, ...) hold the task state of the robots that step in the batch; rows of other robots are stale.
    """

    def __init__(self, envs: list[Any], batch: Any) -> None:
        e0 = envs[0]
        n = len(envs)
        self.envs, self.n = envs, n
        self.qpos, self.qvel, self.ctrl = batch.bind("qpos"), batch.bind("qvel"), batch.bind("ctrl")
        self.userdata, self.time = batch.bind("userdata"), batch.bind("time")
        self.state = batch.state
        sim = e0.sim
        lay = sim.batch_layout()
        self.qs, self.vs, self.motor, self.vel = lay.qpos, lay.qvel, lay.ctrl_torque, lay.ctrl_velocity
        self.ud = lay.reflex_record  # the robot's reflex record in userdata
        self.q_min, self.q_max, self.dq_max_reflex = lay.q_min, lay.q_max, lay.dq_max
        self.q_lo_fail, self.q_hi_fail = e0._q_lo_fail, e0._q_hi_fail
        # both position checks of ``anomalies`` in one: q < q_min or q < q_lo_fail is q < max(q_min, q_lo_fail)
        self.q_lo_any, self.q_hi_any = np.maximum(self.q_min, self.q_lo_fail), np.minimum(self.q_max, self.q_hi_fail)
        self.act_lo, self.act_hi = e0._act_lo_tol, e0._act_hi_tol
        self.act_shape = e0._act_shape
        self.act_scale = e0.action_scale  # (None: physical actions)
        self.guard = e0 if e0.joint_limit_guard else None  # (FrankaEnv.guard_bounds: the same for every robot)
        # rate-limited commands go to the limiter's target in the robot's record, not to the controls
        self.limited = sim.command_rates == "limit"
        self.target = lay.reflex_record + plant.L0 + 4 + np.arange(7)
        self.torque = e0.action_type == "torque"
        self.tau_max = sim.tau_max
        self.neg_tau_max = -self.tau_max
        self.dq_lim = sim.dq_max * VELOCITY_COMMAND_SCALE
        self.friction = sim.model.friction  # the robot's model's law (the same configuration for every robot)
        self.friction_on = np.zeros(n, dtype=np.bool_)
        self.control_state = FORCE_TORQUE if self.torque else VELOCITY
        self.max_steps, self.failure_penalty = e0.max_steps, e0.failure_penalty
        self.n_substeps = e0.n_substeps
        self.steps = np.zeros(n, dtype=np.int64)
        self.t0 = np.zeros(n)
        self.action = np.zeros((n, *self.act_shape))
        pack = e0._pack
        self.pack_items, self.pack_low, self.pack_high = pack.items, pack.low, pack.high
        self.pack_size = pack.low.size
        self.last_obs = np.zeros((n, self.pack_size), dtype=np.float32)  # the last packed observation of each
        self._v = np.empty((n, self.pack_size))  # the packing work matrix when all robots step here
        # observation noise: drawn robot by robot from each environment's own generator, in a single env's order
        self.joint_noise, self.velocity_noise = e0.joint_noise, e0.velocity_noise
        self.rng: list[Any] = [None] * n

    # ------------------------------------------------------------------ which robots step here
    @classmethod
    def supports(cls, env: Any) -> bool:
        """Whether this environment's configuration can step in the batch (the same for every robot)."""
        sim = env.sim
        return (env.action_type in ("torque", "joint_velocity")
                and type(env)._step_begin is _base_step_begin() and sim.batch_layout().reflex_record >= 0
                and (sim.command_rates == "pass" or sim.limits_commands_in_plant)
                and len(env.world.scene.robots) == 1
                and set(env._pack.keys) == set(env.observation_space.spaces))

    def eligible(self, env: Any) -> bool:
        """Whether this robot can step in the batch now (nothing per robot pending)."""
        return (env._diverged is None and env._last_obs is not None and env._pack.last is not None
                and env.sim.runs_inside_mj_step(self.control_state))

    # ------------------------------------------------------------------ moving a robot in and out
    def load(self, i: int) -> None:
        """Robot i's state from its environment into the batch."""
        env = self.envs[i]
        mujoco.mj_getState(env.world.model, env.world.data, self.state[i], _STATE)
        self.steps[i], self.t0[i] = env._steps, env._t0
        self.friction_on[i] = env.sim.friction_enabled
        self.last_obs[i] = env._pack.last
        self.rng[i] = env.np_random  # (a reset with a seed makes a new one: resets happen in the environment)

    def store(self, i: int) -> None:
        """Robot i's state from the batch into its environment (its MjData and attributes)."""
        env = self.envs[i]
        mujoco.mj_setState(env.world.model, env.world.data, self.state[i], _STATE)
        env._steps, env._t0 = int(self.steps[i]), float(self.t0[i])
        env._reflex = None
        buf = env._pack.last = self.last_obs[i].copy()
        env._last_obs = {k: buf[sl].reshape(shape) for k, sl, shape in self.pack_items}
        env.sim.commands_from_controls()

    # ------------------------------------------------------------------ the step
    def rows(self, ids: np.ndarray) -> slice | np.ndarray:
        """The index of the rows ids (sorted, unique) into the (N, ...) arrays: a slice (views, no copies) when
        they are all N robots (the common case), else ids."""
        return slice(None) if len(ids) == self.n else ids

    def check_actions(self, ids: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """The actions (len(ids), k) as float64, checked as ``FrankaEnv._check_action`` checks them: inside the
        space (within its tolerance) in one comparison; other rows go through the robot's own check (which clips
        or raises its error)."""
        if actions.shape[1:] == self.act_shape:
            a = np.array(actions[self.rows(ids)], dtype=np.float64)  # (a copy: the caller's array stays theirs)
            inside = a >= self.act_lo
            inside &= a <= self.act_hi
            if _all(inside, axis=None):
                return a
        rows = [self.envs[i]._check_action(actions[i]) for i in ids]
        return np.array(rows, dtype=np.float64).reshape(len(ids), *self.act_shape)

    def command(self, ids: np.ndarray, a: np.ndarray) -> None:
        """``FrankaEnv._apply_action`` for the rows ids: the torque (saturated at tau_max) or the joint velocity
        (scaled down uniformly within the servo's limit, with the model's friction as feed-forward) into the
        batch's controls."""
        r = self.rows(ids)
        if self.guard is not None:  # the joint-limit guard (FrankaEnv._guard_action) at each robot's q
            lo, hi = self.guard.guard_bounds(self.qpos[r, self.qs])
            a = np.minimum(np.maximum(a, lo), hi)
        if self.act_scale is not None:
            a = a * self.act_scale
        self.action[r] = a
        if self.limited:
            self._command_limited(ids, r, a)
            return
        if self.torque and isinstance(r, slice):  # straight into the batch's controls
            tau = np.minimum(a, self.tau_max, out=self.ctrl[:, self.motor])
            np.maximum(tau, self.neg_tau_max, out=tau)
            return
        x = self._within(a)
        if self.torque:
            self.ctrl[ids, self.motor] = x
            return
        self.ctrl[ids, self.vel] = x
        self._feedforward(ids, x)

    def _within(self, a: np.ndarray) -> np.ndarray:
        """The rows' physical command within the robot's limits: the torque saturated at tau_max, or the joint
        velocity scaled down uniformly within the servo's limit (a new array)."""
        if self.torque:
            tau = np.minimum(a, self.tau_max)
            np.maximum(tau, self.neg_tau_max, out=tau)
            return tau
        ratio = (np.abs(a) / self.dq_lim).max(axis=1)
        over = ratio > 1.0
        dq = a.copy()
        if over.any():
            dq[over] = a[over] / ratio[over, None]
        return dq

    def _feedforward(self, ids: np.ndarray, dq: np.ndarray) -> None:
        """The model's friction at the commanded joint velocity as the motors' feed-forward (where it is on)."""
        ff = self.friction(dq)
        ff[~self.friction_on[ids]] = 0.0
        self.ctrl[ids, self.motor] = ff

    def _command_limited(self, ids: np.ndarray, r: slice | np.ndarray, a: np.ndarray) -> None:
        """The rate-limited command of the rows: the saturated torque or the scaled joint velocity (with its
        friction feed-forward in the motors' controls) into the limiter's target (the plant's callback writes the
        controls at every physics step)."""
        x = self._within(a)
        self.userdata[ids[:, None] if not isinstance(r, slice) else r, self.target] = x
        if not self.torque:
            self._feedforward(ids, x)

    def anomalies(self, ids: np.ndarray) -> np.ndarray:
        """After the physics: rows whose robot must re-run the step alone (a reflex recorded or crossed, a joint at
        its hard stop, a contact); for the others, what the reflexes' after-call check records (the state checked
        at this time)."""
        r = self.rows(ids)
        q, dq = self.qpos[r, self.qs], self.qvel[r, self.vs]
        ud = self.userdata
        out = (q < self.q_lo_any) | (q > self.q_hi_any) | (np.abs(dq) > self.dq_max_reflex)
        bad = _any(out, axis=1)
        bad |= ud[r, self.ud] != ARMED
        if isinstance(r, slice) and not _any(bad):
            ud[:, self.ud + 1] = self.time
            return bad
        ok = ids[~bad]
        ud[ok, self.ud + 1] = self.time[ok]
        return bad

    def joint_state(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The joint positions and velocities (len(ids), 7) of the rows ids (views of the batch's state when they
        are all robots: read them before the next physics step)."""
        r = self.rows(ids)
        return self.qpos[r, self.qs], self.qvel[r, self.vs]

    def observed_joint_state(self, ids: np.ndarray, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``FrankaEnv._noisy_joint_state``: q and dq with the observation noise of each robot's generator."""
        if not (self.joint_noise or self.velocity_noise):
            return q, dq
        q, dq = q.copy(), dq.copy()
        for j, i in enumerate(ids):
            rng = self.rng[i]
            if self.joint_noise:
                q[j] += rng.normal(0.0, self.joint_noise, 7)
            if self.velocity_noise:
                dq[j] += rng.normal(0.0, self.velocity_noise, 7)
        return q, dq

    def pack(self, ids: np.ndarray, raw: dict[str, np.ndarray], out: np.ndarray) -> None:
        """``ObservationPacker`` for the rows ids: raw[key] (len(ids), ...) into out (N, size) float32."""
        m = len(ids)
        v = self._v if m == self.n else np.empty((m, self.pack_size))
        for k, sl, _ in self.pack_items:
            v[:, sl] = raw[k].reshape(m, sl.stop - sl.start)
        if m == self.n:
            clip_observation(v, self.pack_low, self.pack_high, out=out)
            np.copyto(self.last_obs, out)
            return
        packed = clip_observation(v, self.pack_low, self.pack_high)
        out[ids] = packed
        self.last_obs[ids] = packed

    def finish(self, ids: np.ndarray, reward: np.ndarray, success: np.ndarray, failure: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
        """``FrankaEnv._step_end`` after the task's evaluation: (reward, terminated, truncated, info columns) of the
        rows ids; ``failure`` (len(ids),) object (None or the reason), ``success`` bool, or ``failure=None``: no
        row failed (its info column is then all None)."""
        r = self.rows(ids)
        steps = self.steps[r]
        if failure is None:
            failure = np.full(len(ids), None, dtype=object)
            terminated = success & self.terminate_on_success
        else:
            failed = failure != None  # noqa: E711  (elementwise on an object array)
            terminated = (success & self.terminate_on_success) | failed
            success = success & ~failed
            if failed.any():
                reward = reward - np.where(failed, self.failure_penalty * (self.max_steps - steps + 1), 0.0)
        truncated = ~terminated & (steps >= self.max_steps)
        info = {"time": self.time[r] - self.t0[r], "is_success": success, "failure": failure}
        return reward, terminated, truncated, info


def _base_step_begin():
    from franka_vs_gym.envs.base import FrankaEnv

    return FrankaEnv._step_begin


class TorqueTrackingBatch(BatchedTask):
    """FrankaTorqueTracking-v0 over N robots (the task of
    :class:`~franka_vs_gym.envs.torque_tracking.FrankaTorqueTrackingEnv`)."""

    terminate_on_success = False

    def __init__(self, envs: list[Any], batch: Any) -> None:
        super().__init__(envs, batch)
        n = self.n
        self.q0, self.A, self.w = np.zeros((n, 7)), np.zeros((n, 7)), np.zeros((n, 7))
        self.sq_err = np.zeros(n)
        e0 = envs[0]
        self.error_scale, self.success_threshold = e0.error_scale, e0.success_threshold
        self.max_tracking_error = e0.max_tracking_error
        sl = e0._pack._slices
        self.keys = np.array([sl[k].start for k in ("q", "dq", "q_desired", "dq_desired", "ddq_desired", "time")],
                             dtype=np.int64)
        self._cols = np.zeros((4, n))  # reward, error, rms error, success of the rows when all robots step

    def load(self, i: int) -> None:
        super().load(i)
        env = self.envs[i]
        self.q0[i], self.A[i], self.w[i], self.sq_err[i] = env._q0, env._A, env._w, env._sq_err

    def store(self, i: int) -> None:
        super().store(i)
        self.envs[i]._sq_err = float(self.sq_err[i])

    def step_end(self, ids: np.ndarray, out: np.ndarray):
        """FrankaTorqueTrackingEnv._get_obs and _evaluate for the rows ids: one call of the compiled kernel (the
        desired trajectory, the packed observation, the error, its running RMS, success and reward)."""
        r = self.rows(ids)
        self.steps[r] += 1
        m = len(ids)
        allrows = m == self.n
        q, dq = self.joint_state(ids)
        qo, dqo = self.observed_joint_state(ids, q, dq)
        t = self.time[r] - self.t0[r]
        steps = self.steps[r]
        if allrows:
            o, work, sq, cols = out, self._v, self.sq_err, self._cols
        else:
            o, work, sq, cols = np.empty((m, self.pack_size), np.float32), np.empty((m, self.pack_size)), \
                self.sq_err[ids], np.empty((4, m))
        reward, err, rms, success = cols
        c = np.ascontiguousarray
        plant.tracking_batch(c(q), c(qo), c(dqo), t, c(self.q0[r]), c(self.A[r]), c(self.w[r]), sq, c(steps),
                             self.pack_low, self.pack_high, self.keys, work, o, reward, err, rms, success,
                             self.error_scale, self.success_threshold, float(self.max_steps))
        if allrows:
            np.copyto(self.last_obs, o)
        else:
            out[ids] = o
            self.last_obs[ids] = o
            self.sq_err[ids] = sq
        failure = None  # (joint limits and contacts: re-run alone)
        if self.max_tracking_error is not None and (err > self.max_tracking_error).any():
            failure = np.array([tracking_lost(float(e), self.max_tracking_error) for e in err], dtype=object)
        reward, term, trunc, info = self.finish(ids, reward.copy(), success != 0.0, failure)
        info["error"], info["rms_error"] = err.copy(), rms.copy()
        return reward, term, trunc, info


class VisualBatch(BatchedTask):
    """FrankaIBVS-v0, FrankaPBVS-v0, FrankaVisualTorque-v0 and the eye-to-hand tasks over N robots, with the ideal
    projection of the tag corners and feature or state observations (the eye-to-hand truth kernel takes each robot's
    camera placement cMf in place of fMo; its placement in the observation is a per-robot static key). The camera's
    ground truth of all robots (forward kinematics, cMo, the projection, visibility, the pose vector, the feature
    error) is one call of the compiled kernel the single environments use
    (:func:`~franka_vs_gym.envs.kernels.truth_records`), into (N, REC) truth records; the held frames are records
    too (``VisualServoEnv._truth_rec`` / ``_frame_rec``)."""

    def __init__(self, envs: list[Any], batch: Any) -> None:
        super().__init__(envs, batch)
        n, e0 = self.n, envs[0]
        self.kind = type(e0).__name__
        task = _task_class(e0)  # (the eye-to-hand tasks are those of FrankaIBVS-v0 / FrankaPBVS-v0 turned round)
        self.pbvs = task == "FrankaPBVSEnv"
        # observation keys a task writes once per episode (the eye-to-hand camera's placement), per robot
        sl = e0._pack._slices
        self.static = {k: np.zeros((n, sl[k].stop - sl[k].start)) for k in getattr(e0, "_static_keys", ())}
        self.terminate_on_success = e0.terminate_on_success
        self.state_obs = e0.observation_type == "state"
        self.tag_size, self.intrinsics = e0.tag_size, e0.intrinsics
        self.features_desired, self.depth_desired = e0.features_desired, e0.depth_desired
        self.tag_pose_desired, self.cdMo = e0.tag_pose_desired, e0.cdMo
        self.camera_substeps = e0.camera_substeps
        self.feature_noise = e0.feature_noise
        self.terminate_on_tag_lost, self.success_bonus = e0.terminate_on_tag_lost, e0.success_bonus
        self.k = np.zeros(n, dtype=np.int64)
        self.fMo = np.tile(np.eye(4).ravel(), (n, 1))
        e0._plan.refresh(e0)
        # the geometry block every robot in the batch shares (eligible compares each robot's with it)
        self.geo = e0._plan.geo.copy() if e0._plan.geo_or_none is not None else None
        self.truth, self.frame = np.zeros((n, REC)), np.zeros((n, REC))  # the truth now, the held frame
        self.truth_k = np.full(n, -1, dtype=np.int64)
        self._desired_rows = (np.broadcast_to(self.features_desired, (n, 8)),
                              np.broadcast_to(self.tag_pose_desired, (n, 6)))
        if not self.pbvs:
            self.success_threshold, self.error_scale = e0.success_threshold, e0.error_scale
            self.torque_cost = getattr(e0, "torque_cost", 0.0) if self.torque else 0.0
        else:
            self.translation_threshold, self.rotation_threshold = e0.translation_threshold, e0.rotation_threshold
            self.translation_scale, self.rotation_scale = e0.translation_scale, e0.rotation_scale

    @classmethod
    def supports(cls, env: Any) -> bool:
        return (super().supports(env) and env.observation_type in ("features", "state")
                and env.feature_source == "ideal")

    def eligible(self, env: Any) -> bool:
        if not (super().eligible(env) and len(env._segments()) == 1):
            return False
        plan = env._plan
        plan.refresh(env)
        return self.geo is not None and plan.geo_or_none is not None and np.array_equal(plan.geo, self.geo)

    def single_segment(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows whose next period is one physics segment, whether it ends with a camera frame) (len(ids),) each."""
        k0 = self.k[ids]
        k1 = k0 + self.n_substeps
        last = (k1 // self.camera_substeps) * self.camera_substeps
        return (last <= k0) | (last == k1), last > k0

    def load(self, i: int) -> None:
        super().load(i)
        env = self.envs[i]
        self.k[i] = env._k
        self.fMo[i] = env._fMo.ravel()
        self.truth[i], self.frame[i], self.truth_k[i] = env._truth_rec, env._frame_rec, env._truth_k
        for k, rows in self.static.items():  # (as the packer holds them: clipped, which clipping again keeps)
            rows[i] = env._pack._work[env._pack._slices[k]]

    def store(self, i: int) -> None:
        super().store(i)
        env = self.envs[i]
        env._k = int(self.k[i])
        env._truth_rec[:], env._frame_rec[:], env._truth_k = self.truth[i], self.frame[i], int(self.truth_k[i])
        env._frame_no += 1  # the held frame may have changed in the batch: the packer rewrites its keys
        env._packed_frame_no = -1

    def step_end(self, ids: np.ndarray, out: np.ndarray, capture: np.ndarray):
        m = len(ids)
        allrows = m == self.n
        r = self.rows(ids)  # (a slice when all robots step: views instead of fancy-index copies)
        self.steps[r] += 1
        self.k[r] += self.n_substeps
        q, dq = self.joint_state(ids)
        # the truth now (VisualServoEnv._truth_now for all rows)
        rec = self.truth if allrows else np.empty((m, REC))
        truth_records(self.geo, np.ascontiguousarray(q), self.fMo if allrows else self.fMo[ids], rec)
        if not allrows:
            self.truth[ids] = rec
        self.truth_k[r] = self.k[r]
        vis = rec[:, R_VISIBLE] != 0.0
        if allrows and not self.feature_noise and _all(capture):
            # every robot takes a frame (the default periods) without pixel noise: the frame is the truth, zeros
            # where not seen (VisualServoEnv._capture)
            fr = self.frame
            np.copyto(fr, rec)
            if not _all(vis):
                unseen = ~vis
                fr[unseen, R_FEATURES] = 0.0
                fr[unseen, R_DEPTH] = self.depth_desired
                fr[unseen, R_POSE] = 0.0
            cap = ids[:0]
        else:
            cap = ids[capture]
        if len(cap):  # VisualServoEnv._capture: the frame is the truth, zeros where not seen
            sel = capture
            fr = rec[sel].copy()
            if self.feature_noise:  # ideal_measurement with pixel noise: drawn where the tag is in front and facing
                cMo = fr[:, R_CMO].reshape(-1, 4, 4)
                uv, _, Z, _ = project_tag(cMo, self.tag_size, self.intrinsics)
                front = (Z > 1e-6).all(axis=1) & (cMo[:, 2, 2] < 0)
                for j in np.flatnonzero(front):
                    i = cap[j]
                    noisy = uv[j] + self.rng[i].normal(0.0, self.feature_noise, (4, 2))
                    fr[j, R_FEATURES] = self.intrinsics.to_normalized(noisy).ravel()
            unseen = ~vis[sel]
            fr[unseen, R_FEATURES] = 0.0
            fr[unseen, R_DEPTH] = self.depth_desired
            fr[unseen, R_POSE] = 0.0
            self.frame[cap] = fr
        src = rec if self.state_obs else self.frame[r]
        if self.state_obs:
            seen = vis[:, None]
            raw = {"features": np.where(seen, rec[:, R_FEATURES], 0.0),
                   "feature_depth": np.where(seen, rec[:, R_DEPTH], self.depth_desired),
                   "tag_pose": np.where(seen, rec[:, R_POSE], 0.0)}
        else:
            raw = {"features": src[:, R_FEATURES], "feature_depth": src[:, R_DEPTH], "tag_pose": src[:, R_POSE]}
        raw["visible"] = src[:, R_VISIBLE]
        raw["q"], raw["dq"] = self.observed_joint_state(ids, q, dq)
        for k, rows in self.static.items():
            raw[k] = rows if allrows else rows[ids]
        if allrows:
            raw["features_desired"], raw["tag_pose_desired"] = self._desired_rows
        else:
            raw["features_desired"] = np.broadcast_to(self.features_desired, (m, 8))
            raw["tag_pose_desired"] = np.broadcast_to(self.tag_pose_desired, (m, 6))
        self.pack(ids, raw, out)
        # the task's evaluation
        if self.terminate_on_tag_lost and not _all(vis):
            failure = np.full(m, None, dtype=object)
            failure[~vis] = TAG_LOST
            ok = vis  # (failure == None)
        else:
            failure, ok = None, True  # (no row failed: finish writes the info column of Nones)
        extra: dict[str, np.ndarray] = {}
        if self.pbvs:
            et, er = pbvs_errors(self.cdMo, rec[:, R_CMO].reshape(m, 4, 4))
            success = ok & (et < self.translation_threshold) & (er < self.rotation_threshold)
            reward = pose_reward(et, er, self.translation_scale, self.rotation_scale)
            extra = {"error": et, "rotation_error": er}
        else:
            err = rec[:, R_ERROR].copy()
            success = ok & (err < self.success_threshold)
            reward = feature_reward(err, self.error_scale)
            extra = {"error": err}
        reward = success_bonus(reward, success, self.success_bonus)
        if self.kind == "FrankaVisualTorqueEnv" and self.torque_cost:
            reward = reward - torque_penalty(self.action[r], self.tau_max, self.torque_cost)
        reward, term, trunc, info = self.finish(ids, reward, success, failure)
        info.update(extra)
        return reward, term, trunc, info


#: The batched task of each environment class (by class name: subclasses step robot by robot).
TASKS = {"FrankaTorqueTrackingEnv": TorqueTrackingBatch, "FrankaIBVSEnv": VisualBatch,
         "FrankaPBVSEnv": VisualBatch, "FrankaVisualTorqueEnv": VisualBatch,
         "FrankaIBVSEyeToHandEnv": VisualBatch, "FrankaPBVSEyeToHandEnv": VisualBatch}


def _task_class(env: Any) -> str:
    """The name of the registered task class whose evaluation ``env`` runs: its own, or for the eye-to-hand
    classes the eye-in-hand task they derive from."""
    names = [c.__name__ for c in type(env).__mro__]
    for name in ("FrankaPBVSEnv", "FrankaIBVSEnv", "FrankaVisualTorqueEnv"):
        if name in names:
            return name
    return names[0]


def batched_task(envs: list[Any], batch: Any) -> BatchedTask | None:
    """The batched task logic for these environments, or None if their configuration steps robot by robot."""
    cls = TASKS.get(type(envs[0]).__name__)
    if cls is None or type(envs[0]).__module__.split(".")[:2] != ["franka_vs_gym", "envs"]:
        return None
    if not all(cls.supports(e) for e in envs):
        return None
    return cls(envs, batch)


__all__ = ["BatchedTask", "TASKS", "TorqueTrackingBatch", "VisualBatch", "batched_task"]
