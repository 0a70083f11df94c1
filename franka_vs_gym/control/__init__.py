"""Control laws: pure functions and small stateful controllers of the model and the measured signals."""

from franka_vs_gym.control.computed_torque import ComputedTorque

__all__ = ["ComputedTorque"]
