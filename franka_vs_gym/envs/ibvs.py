"""FrankaIBVS-v0: image-based visual servoing of the wrist camera onto an AprilTag."""
# ruff: noqa: E501  (the docstring tables are wider than the code line limit, as in Gymnasium's MuJoCo envs)

from __future__ import annotations

import math
from typing import Any

import numpy as np

from franka_vs_gym.envs.base import FrankaEnv, _positive
from franka_vs_gym.envs.kernels import R_ERROR, R_VISIBLE, TAG_LOST, feature_reward, success_bonus
from franka_vs_gym.envs.visual import VisualServoEnv


class FrankaIBVSEnv(VisualServoEnv):
    """Servo the wrist camera until the AprilTag's four corners reach their goal image positions (the tag centred,
    ``desired_distance`` = 0.20 m in front of the camera, facing it).

    An AprilTag (36h11, ``tag_size`` = 8 cm black square) lies on the table at a random position and yaw. The robot
    starts with the camera 0.26 to 0.40 m from the tag, offset sideways, rolled about its optical axis and tilted,
    with the whole tag in view. The camera sees at its own rate (``camera_period``, 50 ms by default), independent of
    the control period; between frames the observation holds the last frame, as a real camera does.

    ## Action space
    | ``action_type`` | space | unit | executed as |
    |---|---|---|---|
    | ``"joint_velocity"`` (default) | ``Box(-dq_max, dq_max, (7,), float32)`` | rad/s | the robot's joint velocity servo |
    | ``"cartesian_velocity"`` | ``Box([-0.5]*3 + [-1]*3, [0.5]*3 + [1]*3, (6,), float32)`` | m/s, rad/s | camera twist [v; w] in the camera frame c |
    | ``"torque"`` | ``Box(-tau_max, tau_max, (7,), float32)`` | Nm | gravity-free joint torques (the robot adds g(q)) |

    dq_max = (2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61) rad/s; tau_max = (87, 87, 87, 87, 12, 12, 12) Nm.
    Actions are held for ``control_period`` (50 ms). Out-of-space actions raise ``ValueError`` (or are clipped with
    ``clip_actions=True``); NaN/inf always raise.

    ## Observation space
    ``Dict``, float32 except the image (the shared contract of docs/ARCHITECTURE.md):

    | key | shape | unit | meaning | in ``observation_type`` |
    |---|---|---|---|---|
    | ``q`` | (7,) | rad | joint positions (+ ``joint_noise``) | all |
    | ``dq`` | (7,) | rad/s | joint velocities (+ ``velocity_noise``) | all |
    | ``features`` | (8,) | - | tag corners (x0, y0, ..., x3, y3), normalized image coordinates; zeros when not seen | features, features+image, state |
    | ``features_desired`` | (8,) | - | the corners at the goal | features, features+image, state |
    | ``feature_depth`` | (4,) | m | depth Z of each corner in the camera frame (the goal depth when not seen) | features, features+image, state |
    | ``tag_pose`` | (6,) | m, rad | cMo: translation and theta-u (zeros when not seen) | features, features+image, state |
    | ``tag_pose_desired`` | (6,) | m, rad | cdMo, the goal | features, features+image, state |
    | ``visible`` | (1,) | - | 1 when the tag is seen in the current (held) frame | features, features+image, state |
    | ``image`` | (``image_height``, ``image_width``, 3) uint8 | - | the wrist camera image (held frame) | image, features+image |

    ``"features"``: measured by the camera at ``camera_period`` — ideal projection of the true corners plus
    ``feature_noise`` pixels of Gaussian noise (``feature_source="ideal"``, default), or AprilTag detection and pose
    estimation on a rendered ``detection_width`` x ``detection_height`` image (``feature_source="detection"``;
    320 x 240 by default, the camera whose pixels ``feature_noise`` counts; 60 degree vertical field of view).
    ``"state"``: the same keys, exact and at the control rate (privileged information). Values are clipped to the
    space bounds.

    ## Rewards
    ``r = -min(sqrt(||s - s*|| / error_scale), 1)`` per step, in [-1, 0], where ``s - s*`` is the (8,) feature error
    of the true corners (not the noisy, held observation) and ``error_scale`` = 1. The square root keeps the reward
    informative close to the goal (an error of 1 costs 1 per step, 0.1 costs 0.32, 0.01 costs 0.1). Plus
    ``success_bonus`` (1) on success and, on a failure, ``-failure_penalty`` (1) per remaining step of the episode,
    so failing never pays.

    ## Starting state
    Tag at x in ``tag_x_range`` (0.45, 0.60) m, y in ``tag_y_range`` (-0.10, 0.10) m, yaw in ``tag_yaw_range``
    (-0.5, 0.5) rad. Camera at depth ``start_distance_range`` (0.26, 0.40) m from the tag, lateral offset up to
    ``start_offset`` (5 cm at the goal distance, scaled with depth), roll up to ``start_roll`` (0.5 rad), tilt up to
    ``start_tilt`` (0.15 rad), every corner inside 80% of the image; the joint position is found by inverse
    kinematics, at rest. ``reset(options={"q0": q})`` starts from a given joint position instead.

    ## Episode end
    | kind | condition | ``info`` |
    |---|---|---|
    | termination (success) | ``||s - s*|| < success_threshold`` (0.01: about 0.7 pixel per corner coordinate on the 320x240 camera) | ``is_success`` True |
    | termination (failure) | a tag corner leaves the image or the tag gets behind the camera (``terminate_on_tag_lost``), a joint limit is reached, the arm touches the table, the simulation diverges | ``failure``: the reason |
    | truncation | ``time_limit`` (5 s = 100 steps) elapsed | ``is_success`` False |

    ``info`` also holds ``error`` (``||s - s*||`` of the true corners), ``time`` (s since the episode start) and,
    at reset, the randomised dynamics parameters.

    ## Arguments
    ``action_type``, ``observation_type``, ``control_period`` (0.05 s), ``physics_step`` (0.001 s),
    ``camera_period`` (0.05 s), ``time_limit`` (5 s), ``tag_size``, ``tag_id``, ``tag_x_range``, ``tag_y_range``,
    ``tag_yaw_range``, ``desired_distance``, ``start_distance_range``, ``start_offset``, ``start_roll``,
    ``start_tilt``, ``feature_noise`` (pixels), ``feature_source``, ``joint_noise``, ``velocity_noise``,
    ``link_mass_range``, ``friction_scale_range``, ``payload_mass_range``, ``payload_declared``, ``model``
    (calibrated model file),
    ``image_width``, ``image_height``, ``render_mode`` ("rgb_array"), ``render_width``, ``render_height``,
    ``success_threshold``, ``error_scale``, ``success_bonus``, ``failure_penalty``, ``clip_actions``.
    """

    def __init__(self, *, action_type: str = "joint_velocity", control_period: float = 0.05,
                 time_limit: float = 5.0, success_threshold: float = 0.01, error_scale: float = 1.0,
                 **kwargs: Any) -> None:
        self.success_threshold = _positive(success_threshold, "success_threshold")
        self.error_scale = _positive(error_scale, "error_scale")
        super().__init__(action_type=action_type, control_period=control_period, time_limit=time_limit, **kwargs)
        cls = type(self)
        # the compiled step ends in one call (_end_compiled) when this task's evaluation is the one it stands for
        self._plan.task_end = (cls._evaluate is cls._end_compiled_evaluates
                               and cls._task_error is FrankaIBVSEnv._task_error and cls._seen is VisualServoEnv._seen
                               and cls._finish_step is FrankaEnv._finish_step
                               and cls._robot_failure is FrankaEnv._robot_failure)
        self._end_cost = 0.0  # (FrankaVisualTorque-v0: the torque cost is subtracted, see _end_compiled)

    def _task_error(self) -> float:
        return float(self._truth_now()[R_ERROR])

    def _evaluate(self, action: np.ndarray) -> tuple[float, bool, str | None, dict[str, Any]]:
        err = self._task_error()
        failure = None
        if self.terminate_on_tag_lost and not self._seen():
            failure = TAG_LOST
        success = failure is None and err < self.success_threshold
        reward = success_bonus(feature_reward(err, self.error_scale), success, self.success_bonus)
        return reward, success, failure, {"error": err}

    #: the evaluation _end_compiled stands for (a subclass that overrides _evaluate ends its compiled steps through
    #: FrankaEnv._finish_step, unless it names its own evaluation here and _end_compiled does what it does)
    _end_compiled_evaluates = _evaluate

    def _end_compiled(self, obs: dict[str, np.ndarray], code: int):
        """The end of a compiled step (``StepPlan.step``) in one call: ``FrankaEnv._finish_step`` with this task's
        ``_evaluate``, on the truth record the compiled period end has just written (the same arithmetic, so the
        same bits; FrankaVisualTorque-v0's torque cost is the compiled command's, ``plan.cost_now``)."""
        self._last_obs = obs
        plan = self._plan
        t = plan.truth
        err = float(t[R_ERROR])
        failure = TAG_LOST if self.terminate_on_tag_lost and not t[R_VISIBLE] else None
        success = failure is None and err < self.success_threshold
        reward = -min(math.sqrt(err / self.error_scale), 1.0) + (self.success_bonus if success else 0.0)
        if self._end_cost:
            reward -= float(plan.cost_now[0])
        if failure is None and code == 1:
            failure = self._robot_failure()
        if failure is not None:
            success = False
            reward -= self._failure_cost()
            terminated = True
        else:
            terminated = bool(success and self.terminate_on_success)
        truncated = (not terminated) and self._steps >= self.max_steps
        # (the time: episode_time's, from the data the plant steps)
        info = {"time": self._d.time - self._t0, "is_success": success, "failure": failure, "error": err}
        return obs, float(reward), terminated, truncated, info
