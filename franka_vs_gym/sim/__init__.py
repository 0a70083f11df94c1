"""Simulation: the MuJoCo world built from the model parameters and the vpRobotFranka-style robot API."""

from franka_vs_gym.sim import plant
from franka_vs_gym.sim.robot import (
                                     CAMERA_FRAME,
                                     END_EFFECTOR_FRAME,
                                     FORCE_TORQUE,
                                     JOINT_STATE,
                                     POSITION,
                                     REFERENCE_FRAME,
                                     STOP,
                                     VELOCITY,
                                     ControlFrame,
                                     FrankaSim,
                                     RobotState,
                                     pose_vector,
                                     twist_transform,
)
from franka_vs_gym.sim.world import SimulationDiverged, SimWorld

__all__ = ["CAMERA_FRAME", "END_EFFECTOR_FRAME", "FORCE_TORQUE", "JOINT_STATE", "POSITION", "REFERENCE_FRAME",
           "STOP", "VELOCITY", "ControlFrame", "FrankaSim", "RobotState", "SimWorld", "SimulationDiverged", "plant",
           "pose_vector", "twist_transform"]
