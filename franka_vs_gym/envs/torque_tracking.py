"""FrankaTorqueTracking-v0: track a desired joint trajectory with gravity-free torque commands."""
# ruff: noqa: E501  (the docstring tables are wider than the code line limit, as in Gymnasium's MuJoCo envs)

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from franka_vs_gym.envs.base import FrankaEnv, ObservationPacker, _positive
from franka_vs_gym.envs.compiled import TrackingStep
from franka_vs_gym.envs.kernels import tracking_reward, tracking_rows


class FrankaTorqueTrackingEnv(FrankaEnv):
    """Track a smooth desired joint trajectory with joint torques (the FrankaSim tracking experiment as a task).

    Each episode draws a start posture ``q0`` around the neutral pose and, per joint, an amplitude ``A`` and a
    frequency ``f``; the desired trajectory is ``q_d(t) = q0 + A (1 - cos(2 pi f t))`` (it starts at rest at ``q0``).
    The robot starts at ``q0`` at rest. Torques are gravity-free, as with libfranka: the simulated robot adds g(q)
    itself; friction, Coriolis and inertia are the policy's job.

    ## Action space
    ``action_type="torque"`` (default): ``Box(-1, 1, (7,), float32)``, gravity-free joint torques normalized by
    the task's torque scale (``env.unwrapped.action_scale``, Nm: the torque that gives every joint the fastest
    desired trajectory's peak acceleration ``amplitude (2 pi f_max)^2`` at once at the neutral posture, plus
    friction at its peak velocity; FER 3.5, 7.3, 4.9, 5.9, 0.9, 0.9, 0.35 Nm with the defaults; see
    :func:`~franka_vs_gym.envs.base.torque_action_scale`); ``action_scale="physical"``: ``Box(-tau_max, tau_max)``
    Nm (tau_max = 87, 87, 87, 87, 12, 12, 12 Nm). ``action_type="joint_velocity"``: ``Box(-1, 1)`` times half the
    rated joint velocities (``Box(-dq_max, dq_max)`` rad/s with ``action_scale="physical"``), executed by the
    robot's joint velocity servo. Commands pass through the robot interface's rate limiter (``limit_rate``). Out-of-space actions raise ``ValueError`` unless
    ``clip_actions=True``; NaN/inf always raise.

    ## Observation space
    ``Dict``, float32 (``observation_type="state"``, the only one of this task):

    | key | shape | unit | meaning |
    |---|---|---|---|
    | ``q`` | (7,) | rad | measured joint positions (+ ``joint_noise``) |
    | ``dq`` | (7,) | rad/s | measured joint velocities (+ ``velocity_noise``) |
    | ``q_desired`` | (7,) | rad | desired joint positions at the current time |
    | ``dq_desired`` | (7,) | rad/s | desired joint velocities |
    | ``ddq_desired`` | (7,) | rad/s^2 | desired joint accelerations |
    | ``time`` | (1,) | s | time since the start of the episode |

    Values are clipped to the space bounds (joint limits +-0.2 rad, 2 dq_max, ...).

    ## Rewards
    ``r = -min(||q - q_d|| / error_scale, 1)`` per step, in [-1, 0] (``error_scale`` = 0.1 rad by default), and on a
    failure a penalty of ``failure_penalty`` (1) per remaining step of the episode.

    ## Starting state
    ``q0`` = neutral pose + U(-0.3, 0.3) rad per joint (kept 0.3 rad inside the limits along the whole trajectory),
    ``A`` = U(0.05, amplitude) rad with a random sign, ``f`` = U(frequency_range) Hz; the robot at rest at ``q0``.

    ## Episode end
    | kind | condition | ``info`` |
    |---|---|---|
    | termination (failure) | the tracking error ``||q - q_d||`` above ``max_tracking_error`` (0.3 rad; None: never), a joint limit reached, the arm touches the table, or the simulation diverges | ``failure``: the reason |
    | truncation | ``time_limit`` (5 s) elapsed | ``is_success``: RMS tracking error over the episode < ``success_threshold`` (0.02 rad) |

    ``info`` also holds ``error`` (current ||q - q_d||, rad), ``rms_error`` (so far), ``time`` (s).

    ## Arguments
    Those of :class:`~franka_vs_gym.envs.base.FrankaEnv` (``action_type``, ``control_period`` (default 0.01 s =
    100 Hz; 0.001 s for libfranka's 1 kHz), ``physics_step``, ``time_limit``, ``model``, domain randomisation
    (``link_mass_range``, ``friction_scale_range``, ``payload_mass_range``, ``payload_declared``),
    noise, ``render_mode``) and ``amplitude`` (rad), ``frequency_range`` (Hz), ``error_scale`` (rad),
    ``success_threshold`` (rad).
    """

    supported_action_types = ("torque", "joint_velocity")
    supported_observation_types = ("state",)
    terminate_on_success = False  # success is judged on the whole episode, at its end

    def __init__(self, *, action_type: str = "torque", observation_type: str = "state",
                 control_period: float = 0.01, time_limit: float = 5.0, amplitude: float = 0.3,
                 frequency_range: Any = (0.2, 0.5), error_scale: float = 0.1, success_threshold: float = 0.02,
                 max_tracking_error: float | None = 0.3, **kwargs: Any) -> None:
        self.amplitude = _positive(amplitude, "amplitude")
        if self.amplitude < 0.05 or self.amplitude > 0.6:
            raise ValueError(f"amplitude must be in [0.05, 0.6] rad, got {amplitude}")
        fr = np.asarray(frequency_range, dtype=np.float64)
        if fr.shape != (2,) or not np.isfinite(fr).all() or not 0 < fr[0] <= fr[1]:
            raise ValueError(f"frequency_range must be a (low, high) pair of Hz with 0 < low <= high, got "
                             f"{frequency_range!r}")
        self.frequency_range = (float(fr[0]), float(fr[1]))
        self.max_tracking_error = None if max_tracking_error is None else _positive(max_tracking_error,
                                                                                    "max_tracking_error")
        # the default torque scale covers the fastest desired trajectory: its peak acceleration A (2 pi f)^2 for
        # every joint at once, friction at its peak velocity A 2 pi f
        w = 2 * np.pi * self.frequency_range[1]
        self.torque_scale_motion = (self.amplitude * w * w, self.amplitude * w)
        super().__init__(action_type=action_type, observation_type=observation_type, control_period=control_period,
                         time_limit=time_limit, camera=False, **kwargs)
        self.error_scale = _positive(error_scale, "error_scale")
        self.success_threshold = _positive(success_threshold, "success_threshold")
        q_lo, q_hi = self.q_min - 0.2, self.q_max + 0.2
        dq_hi = 2.0 * self.dq_max
        f32 = np.float32
        self.observation_space = spaces.Dict({
            "q": spaces.Box(q_lo.astype(f32), q_hi.astype(f32), dtype=f32),
            "dq": spaces.Box((-dq_hi).astype(f32), dq_hi.astype(f32), dtype=f32),
            "q_desired": spaces.Box(q_lo.astype(f32), q_hi.astype(f32), dtype=f32),
            "dq_desired": spaces.Box((-dq_hi).astype(f32), dq_hi.astype(f32), dtype=f32),
            "ddq_desired": spaces.Box(f32(-100.0), f32(100.0), (7,), dtype=f32),
            "time": spaces.Box(f32(0.0), f32(self.time_limit + 1.0), (1,), dtype=f32),
        })
        self._pack = ObservationPacker(self.observation_space)
        self._q0 = self.config.robot.neutral()
        self._A = np.zeros(7)
        self._w = np.zeros(7)
        self._sq_err = 0.0
        self._err_now = 0.0
        self._plan = TrackingStep(self)  # the compiled step of torque actions (franka_vs_gym.envs.compiled)

    def _after_reset(self) -> None:
        self._plan.set_trajectory(self._q0, self._A, self._w, self._t0)

    def desired(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q_d, dq_d, ddq_d) (7,) at time t (s since the episode start)."""
        d = self._tracking(t, self._q0)[0]
        return d[:7], d[7:14], d[14:]

    def _tracking(self, t: float, q: np.ndarray) -> tuple[np.ndarray, float]:
        """The desired trajectory (21,: q_d, dq_d, ddq_d) at time t and the tracking error ||q - q_d|| (kernels,
        the batched vector env's formulas)."""
        d, e, tb = np.empty(21), np.empty(1), np.array([float(t)])
        tracking_rows(self._q0, self._A, self._w, tb, np.ascontiguousarray(q, dtype=np.float64), d, e)
        return d, float(e[0])

    def _reset_task(self, options: dict[str, Any]) -> np.ndarray:
        rng = self.np_random
        margin = 0.3
        lo, hi = self.q_min + margin, self.q_max - margin
        neutral = self.config.robot.neutral()
        q0 = np.clip(neutral + rng.uniform(-0.3, 0.3, 7), lo, hi)
        A = rng.uniform(0.05, self.amplitude, 7) * rng.choice([-1.0, 1.0], 7)
        # keep q0 + 2A (the far end of the motion) inside the limits: flip the sign, then shrink if needed
        end = q0 + 2 * A
        flip = (end < lo) | (end > hi)
        A[flip] = -A[flip]
        room = np.where(A > 0, hi - q0, q0 - lo)
        A = np.sign(A) * np.minimum(np.abs(A), np.maximum(room, 0.0) / 2)
        f = rng.uniform(*self.frequency_range, 7)
        self._q0, self._A, self._w = q0, A, 2 * np.pi * f
        self._sq_err = 0.0
        return q0

    def _get_obs(self) -> dict[str, np.ndarray]:
        q, dq = self._noisy_joint_state()
        t = self.episode_time
        d, self._err_now = self._tracking(t, self.sim.joint_views()[0])  # (the error of the true joint positions)
        raw = {"q": q, "dq": dq, "q_desired": d[:7], "dq_desired": d[7:14], "ddq_desired": d[14:], "time": t}
        return self._pack(raw)

    def _evaluate(self, action: np.ndarray) -> tuple[float, bool, str | None, dict[str, Any]]:
        err = self._err_now  # computed with this step's observation
        self._sq_err += err * err
        rms = float(np.sqrt(self._sq_err / max(self._steps, 1)))
        success = self._steps >= self.max_steps and rms < self.success_threshold
        reward = tracking_reward(err, self.error_scale)
        failure = tracking_lost(err, self.max_tracking_error)
        return reward, success, failure, {"error": err, "rms_error": rms}


def tracking_lost(err: float, max_error: float | None) -> str | None:
    """The failure reason of a tracking error beyond ``max_error`` (rad; None: never)."""
    if max_error is not None and err > max_error:
        return f"tracking lost: error {err:.4f} rad > max_tracking_error {max_error} rad"
    return None
