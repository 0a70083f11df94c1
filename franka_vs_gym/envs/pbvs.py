"""FrankaPBVS-v0: position-based visual servoing: the same scene as FrankaIBVS-v0, judged on the camera pose."""
# ruff: noqa: E501  (the docstring tables are wider than the code line limit, as in Gymnasium's MuJoCo envs)

from __future__ import annotations

from typing import Any

import numpy as np

from franka_vs_gym.envs.base import _positive
from franka_vs_gym.envs.kernels import R_CMO, TAG_LOST, pbvs_errors, pose_reward, success_bonus
from franka_vs_gym.envs.visual import VisualServoEnv


class FrankaPBVSEnv(VisualServoEnv):
    """Bring the wrist camera to the goal pose relative to the AprilTag (cdMo: tag centred, 0.20 m in front).

    Scene, starting state, action and observation spaces, camera timing and arguments are those of
    :class:`~franka_vs_gym.envs.ibvs.FrankaIBVSEnv` (the observation carries the same contract keys; a PBVS agent
    typically uses ``tag_pose`` and ``tag_pose_desired``). Only the error, reward and success differ.

    ## Action space
    ``action_type`` = ``"joint_velocity"`` (default, (7,) rad/s), ``"cartesian_velocity"`` ((6,) camera twist in c,
    m/s and rad/s, +-0.5 / +-1) or ``"torque"`` ((7,) Nm gravity-free). See FrankaIBVS-v0.

    ## Observation space
    As FrankaIBVS-v0: ``q``, ``dq``, ``features``, ``features_desired``, ``feature_depth``, ``tag_pose`` (cMo,
    (6,) m and rad, theta-u), ``tag_pose_desired`` (cdMo), ``visible``, and ``image`` with image observations.

    ## Rewards
    With the pose error ``cdMc = cdMo (cMo)^-1`` of the true camera pose, ``t`` its translation (m) and ``theta u``
    its rotation (rad): ``r = -min(||t|| / translation_scale + ||theta u|| / rotation_scale, 1)`` per step
    (scales 0.2 m and 1 rad), plus ``success_bonus`` (1) on success; a failure costs ``failure_penalty`` (1) per
    remaining step.

    ## Episode end
    | kind | condition | ``info`` |
    |---|---|---|
    | termination (success) | ``||t|| < translation_threshold`` (5 mm) and ``||theta u|| < rotation_threshold`` (0.02 rad) | ``is_success`` True |
    | termination (failure) | tag out of the image (``terminate_on_tag_lost``), joint limit, arm on the table, divergence | ``failure``: the reason |
    | truncation | ``time_limit`` (5 s) elapsed | ``is_success`` False |

    ``info["error"]`` is ``||t||`` (m) and ``info["rotation_error"]`` is ``||theta u||`` (rad).
    """

    def __init__(self, *, action_type: str = "joint_velocity", control_period: float = 0.05,
                 time_limit: float = 5.0, translation_threshold: float = 0.005, rotation_threshold: float = 0.02,
                 translation_scale: float = 0.2, rotation_scale: float = 1.0, **kwargs: Any) -> None:
        self.translation_threshold = _positive(translation_threshold, "translation_threshold")
        self.rotation_threshold = _positive(rotation_threshold, "rotation_threshold")
        self.translation_scale = _positive(translation_scale, "translation_scale")
        self.rotation_scale = _positive(rotation_scale, "rotation_scale")
        super().__init__(action_type=action_type, control_period=control_period, time_limit=time_limit, **kwargs)

    def _pose_error(self) -> tuple[float, float]:
        et, er = pbvs_errors(self.cdMo, self._truth_now()[R_CMO].reshape(1, 4, 4))
        return float(et[0]), float(er[0])

    def _task_error(self) -> float:
        return self._pose_error()[0]

    def _evaluate(self, action: np.ndarray) -> tuple[float, bool, str | None, dict[str, Any]]:
        et, er = self._pose_error()
        failure = None
        if self.terminate_on_tag_lost and not self._seen():
            failure = TAG_LOST
        success = failure is None and et < self.translation_threshold and er < self.rotation_threshold
        reward = success_bonus(pose_reward(et, er, self.translation_scale, self.rotation_scale), success,
                               self.success_bonus)
        return reward, success, failure, {"error": et, "rotation_error": er}
