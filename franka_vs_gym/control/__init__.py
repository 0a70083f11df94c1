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

__all__ = ["CartesianComputedTorque", "CartesianImpedance", "ComputedTorque", "GravityCompensation",
           "JointImpedance", "circle_reference", "null_space_projector", "pose_error"]
