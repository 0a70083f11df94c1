"""FrankaVisualTorque-v0: image-based visual servoing with joint torque commands (dynamic visual servoing)."""
# ruff: noqa: E501  (the docstring tables are wider than the code line limit, as in Gymnasium's MuJoCo envs)

from __future__ import annotations

from typing import Any

from franka_vs_gym.envs.ibvs import FrankaIBVSEnv
from franka_vs_gym.envs.kernels import torque_penalty


class FrankaVisualTorqueEnv(FrankaIBVSEnv):
    """The FrankaIBVS-v0 task driven by gravity-free joint torques at a fast control rate: the policy closes the
    visual loop *and* handles the arm's dynamics (inertia, Coriolis, friction), as a dynamic visual-servoing
    controller on the FER's torque interface does.

    Differences from FrankaIBVS-v0 (whose tables apply otherwise):

    | | FrankaIBVS-v0 | FrankaVisualTorque-v0 |
    |---|---|---|
    | default ``action_type`` | ``"joint_velocity"`` | ``"torque"``: (7,) Nm, gravity-free, ``Box(-tau_max, tau_max)`` |
    | ``control_period`` | 0.05 s | 0.005 s (200 Hz) |
    | ``camera_period`` | 0.05 s | 0.02 s (50 Hz; features held between frames) |
    | ``time_limit`` | 5 s (100 steps) | 5 s (1000 steps) |
    | reward | sqrt of the feature error (see FrankaIBVS-v0) | the same, minus ``torque_cost`` * ``||tau / tau_max||^2 / 7`` (0.01) |

    ## Rewards
    ``r = r_IBVS - torque_cost * mean((tau / tau_max)^2)`` per step, in [-1.01, 0], where ``r_IBVS`` is
    FrankaIBVS-v0's square-root feature-error reward; plus ``success_bonus`` on success; a failure costs
    ``failure_penalty`` per remaining step.

    ## Episode end
    As FrankaIBVS-v0: success when ``||s - s*|| < success_threshold`` (0.01); failure when the tag leaves the image,
    a joint limit is reached, the arm touches the table or the simulation diverges; truncation at ``time_limit``.
    """

    def __init__(self, *, action_type: str = "torque", control_period: float = 0.005, camera_period: float = 0.02,
                 time_limit: float = 5.0, torque_cost: float = 0.01, **kwargs: Any) -> None:
        if not (torque_cost >= 0):
            raise ValueError(f"torque_cost must be >= 0, got {torque_cost!r}")
        self.torque_cost = float(torque_cost)
        super().__init__(action_type=action_type, control_period=control_period, camera_period=camera_period,
                         time_limit=time_limit, **kwargs)
        self._end_cost = self.action_type == "torque" and bool(self.torque_cost)  # (what _evaluate subtracts)

    def _evaluate(self, action):
        reward, success, failure, info = super()._evaluate(action)
        if self.action_type == "torque" and self.torque_cost:
            plan = self._plan
            # (the compiled step computed the cost of its action, plan.action, with the kernel's formula)
            reward -= float(plan.cost_now[0]) if action is plan.action else torque_penalty(action, self.tau_max,
                                                                                          self.torque_cost)
        return reward, success, failure, info

    _end_compiled_evaluates = _evaluate  # (FrankaIBVSEnv._end_compiled subtracts the compiled command's torque cost)
