"""Control laws: pure functions and small stateful controllers of the model and the measured signals."""

from franka_vs_gym.control.cartesian import CartesianComputedTorque, circle_reference
from franka_vs_gym.control.computed_torque import ComputedTorque
from franka_vs_gym.control.impedance import (
    CartesianImpedance,
    GravityCompensation,
    JointImpedance,
    null_space_projector,
    pose_error,
)
from franka_vs_gym.control.visual_servo import (
    AdaptiveGain,
    InteractionMatrixType,
    camera_to_joint_velocity,
    ibvs_velocity,
    pbvs_velocity,
)

__all__ = ["AdaptiveGain", "CartesianComputedTorque", "CartesianImpedance", "ComputedTorque", "GravityCompensation",
           "InteractionMatrixType", "JointImpedance", "camera_to_joint_velocity", "circle_reference", "ibvs_velocity",
           "null_space_projector", "pbvs_velocity", "pose_error"]
