"""A single environment's control period in compiled code (``franka_vs_gym/sim/_task.c``), for torque and joint
velocity actions.

A step of the common configuration (joint-torque or joint-velocity actions inside the action space, the compiled
plant with the robot's reflexes armed, commands passed as given or through the plant's rate limiter, no observation
noise) is two compiled calls around ``mujoco.mj_step``: the command (``visual_pre``: the action checked, multiplied
by the action scale, then saturated at tau_max and written where ``FrankaSim.set_force_torque`` writes it, or
scaled within the velocity servo's limit and written, with the model's feed-forward friction, where
``FrankaSim.set_velocity`` writes it) and the period's end (the
reflex check of the state the period ends with, the task's quantities, the observation packed and clipped into a
fresh float32 buffer, a joint at its failure bound or a contact flagged). Python then ends the step as the general
path does (``FrankaEnv._finish_step``). Anything else (another action form, a diverging state, a reflex, noise,
images, delays...) takes the general path; both give the same bits (``tests/test_task_kernels.py``).

The numbers both halves read and write live in one float64 block ``P`` and one int64 block ``I`` (layout in
``_task.c``): the task's block (the visual tasks' geometry, torque tracking's trajectory), records, the action
bounds, the observation packer's work vector and bounds (the packer writes into the same memory), MuJoCo addresses
and the observation's key offsets.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from franka_vs_gym.envs.kernels import GEO, REC
from franka_vs_gym.sim import FORCE_TORQUE, VELOCITY, SimulationDiverged, plant
from franka_vs_gym.sim.reflexes import ControlException
from franka_vs_gym.sim.robot import VELOCITY_COMMAND_SCALE


class CompiledStep:
    """The blocks shared with the compiled step of one environment, and the calls around its physics.

    Subclasses name the observation keys of the block's key slots (``KEYS``), the task's own views and the
    period's end (:meth:`step`)."""

    KEYS: tuple[str, ...] = ()

    def __init__(self, env: Any, fast: bool) -> None:
        pack = env._pack
        S = pack.low.size
        self.size = S
        self.P = np.zeros(plant.TASK_P_FIXED + 3 * S)
        self.I = np.zeros(plant.TASK_I_SIZE, dtype=np.int64)
        self._bind()
        self.work[:] = pack._work
        pack._work = self.work  # (the packer writes into it in place)
        self.low[:], self.high[:] = pack.low, pack.high
        self.views = pack._views
        sim = env.sim
        # the configuration the compiled step covers (the per-step conditions are in eligible)
        self.fast = (fast and plant.visual_pre is not None and env.action_type in ("torque", "joint_velocity")
                     and not env.joint_noise and not env.velocity_noise
                     and set(pack.keys) <= set(self.KEYS) | set(getattr(env, "_static_keys", ()))
                     and type(env).__module__.startswith("franka_vs_gym.envs."))
        self.velocity = env.action_type == "joint_velocity"
        self.control_state = VELOCITY if self.velocity else FORCE_TORQUE
        I = self.I
        lay = sim.batch_layout()
        I[0] = lay.first_joint
        I[1:8] = np.arange(lay.qpos.start, lay.qpos.stop)
        I[8:15] = np.arange(lay.qvel.start, lay.qvel.stop)
        I[15] = lay.ctrl_torque.start
        for j, k in enumerate(self.KEYS):
            I[16 + j] = pack._slices[k].start if k in pack._slices else -1
        I[16 + len(self.KEYS):24] = -1
        I[24] = S
        I[25] = -1
        I[26] = 2 if self.velocity else 1
        I[27] = lay.ctrl_velocity.start
        I[28] = 0
        # the rate limiter's target in the data's userdata (where set_force_torque leaves a rate-limited command)
        self._lim_index = lay.reflex_record + plant.L0 + 4 if lay.reflex_record >= 0 else -1
        self._sim = sim
        self.act_scale[:] = 1.0
        if env.action_type in ("torque", "joint_velocity"):
            self.act_lo[:], self.act_hi[:] = env._act_lo_tol, env._act_hi_tol
            if env.action_scale is not None:
                self.act_scale[:] = env.action_scale
        self.tau_max[:] = sim.tau_max
        self.dq_cap[:] = sim.dq_max * VELOCITY_COMMAND_SCALE  # (FrankaSim.set_velocity's product, the same bits)
        self._ff: Any = None  # the feed-forward friction the block holds (FrankaSim.feedforward_friction)
        self.q_lo[:], self.q_hi[:] = env._q_lo_fail, env._q_hi_fail
        self.n_substeps = env.n_substeps
        self.model, self.data = env.world.model, env.world.data
        self.m_addr, self.d_addr = self.model._address, self.data._address
        self._cmd_views = sim.velocity_command_views() if self.velocity else sim.torque_command_views()

    def _bind(self) -> None:
        """The named views of the float64 block P (the layout of franka_vs_gym/sim/_task.c)."""
        P, S = self.P, self.size
        self.geo = P[:GEO]  # the task's block (the visual tasks' geometry, torque tracking's trajectory)
        self.fMo = P[GEO:GEO + 16].reshape(4, 4)
        self.truth = P[GEO + 16:GEO + 16 + REC]
        self.frame = P[GEO + 16 + REC:GEO + 16 + 2 * REC]
        o = GEO + 16 + 2 * REC
        self.act_lo, self.act_hi, self.tau_max, self.action = (P[o:o + 7], P[o + 7:o + 14], P[o + 14:o + 21],
                                                                P[o + 21:o + 28])
        self.q_lo, self.q_hi = P[o + 28:o + 35], P[o + 35:o + 42]
        self.depth_d, self.pose_d, self.cost = P[o + 42:o + 46], P[o + 46:o + 52], P[o + 52:o + 53]
        self.cost_now = P[o + 53:o + 54]
        self.act_scale = P[o + 54:o + 61]
        self.dq_cap = P[o + 61:o + 68]
        self.friction = P[o + 68:o + 96].reshape(4, 7)  # phi1, phi2, phi2 phi3, offset
        w0 = plant.TASK_P_FIXED
        if o + 96 != w0:
            raise RuntimeError("the step plan's layout differs from franka_vs_gym/sim/_task.c's")
        self.work, self.low, self.high = P[w0:w0 + S], P[w0 + S:w0 + 2 * S], P[w0 + 2 * S:w0 + 3 * S]

    def __setstate__(self, state: dict[str, Any]) -> None:
        """A copy (``copy.deepcopy`` of the environment) gets its own block: the views are made again from it and
        the MuJoCo addresses are those of the copy's model and data (the environment re-points its packer)."""
        self.__dict__.update(state)
        self._bind()
        self.m_addr, self.d_addr = self.model._address, self.data._address

    def eligible(self, env: Any) -> bool:
        """Whether the next control period can run in the compiled step."""
        return env.sim.runs_inside_mj_step(self.control_state)

    def _feedforward(self) -> bool:
        """Joint velocity actions: the block's feed-forward friction made current (FrankaSim.set_velocity's: none
        with the friction off, the model's sigmoid law); False when the model's law is another one (the general path
        then computes it)."""
        ff = self._sim.feedforward_friction()
        if ff is not self._ff:
            self._ff = ff
            if ff:
                self.friction[:] = ff
            self.I[28] = 1 if ff else 0
        return ff is not None

    def command(self, env: Any, action: Any) -> bool:
        """The action into the controls and the period's physics; False (nothing done) when the action is not a
        plain vector inside the action space (the general path then checks it, clips it or names the problem)."""
        self.I[25] = self._lim_index if self._sim.rate_limiter_active else -1
        if self.velocity and not self._feedforward():
            return False
        if plant.visual_pre(self.P, self.I, self.d_addr, action, *self._cmd_views) < 0:
            return False
        env._reflex = None
        env._action = self.action
        mujoco.mj_step(self.model, self.data, self.n_substeps)
        return True

    @staticmethod
    def general_end(env: Any, n: int, capture: bool):
        """The rest of a period whose end the compiled call left to Python (a diverging state or a reflex): what
        ``SimWorld.step`` and ``FrankaEnv.step`` do after the physics."""
        try:
            env.world.after_steps()
            env._segment_done(n, capture)
        except SimulationDiverged as e:
            return env._step_diverged(e)
        except ControlException as e:
            env._reflex = e
        return env._step_end()

    def finish(self, env: Any, out: np.ndarray, code: int):
        """The step's end in Python from the packed observation ``out``."""
        env._pack.last = out
        env._steps += 1
        obs = {k: out[sl] if sh is None else out[sl].reshape(sh) for k, sl, sh in self.views}
        return env._finish_step(obs, check_robot=code == 1)

    def step(self, env: Any, action: Any):
        """One control period in the compiled step; None (nothing done) when the action is not a plain vector inside
        the action space."""
        raise NotImplementedError

    def post(self, out: np.ndarray) -> int:
        """The compiled period end alone on the current state (no camera frame taken), for benchmarks."""
        raise NotImplementedError


class TrackingStep(CompiledStep):
    """FrankaTorqueTracking-v0's compiled step: the desired trajectory, the packed observation and the tracking error
    (``tracking_post``; the trajectory's q0, A, w and the episode's start time in the task's block)."""

    KEYS = ("q", "dq", "q_desired", "dq_desired", "ddq_desired", "time")

    def __init__(self, env: Any) -> None:
        super().__init__(env, fast=plant.tracking_post is not None)

    def set_trajectory(self, q0: np.ndarray, A: np.ndarray, w: np.ndarray, t0: float) -> None:
        """The episode's trajectory and start time (at every reset)."""
        g = self.geo
        g[:7], g[7:14], g[14:21], g[21] = q0, A, w, t0

    def step(self, env: Any, action: Any):
        if not self.command(env, action):
            return None
        out = np.empty(self.size, dtype=np.float32)
        code = plant.tracking_post(self.P, self.I, self.m_addr, self.d_addr, out)
        if code < 0:
            return self.general_end(env, self.n_substeps, False)
        env._err_now = float(self.truth[0])
        return self.finish(env, out, code)

    def post(self, out: np.ndarray) -> int:
        return plant.tracking_post(self.P, self.I, self.m_addr, self.d_addr, out)


__all__ = ["CompiledStep", "TrackingStep"]
