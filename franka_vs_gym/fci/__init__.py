"""libfranka's network interface (FCI) in front of the simulated FER: unmodified client code runs on the simulator.

``franka-vs serve`` / :class:`FCIServer` speak libfranka's robot protocol (version 10) and gripper protocol
(version 3) with a :class:`~franka_vs_gym.sim.FrankaSim` plant behind them. See :mod:`franka_vs_gym.fci.server`.
"""

from franka_vs_gym.fci.errors import ERROR_NAMES, error_bit
from franka_vs_gym.fci.robot import FCIRobot
from franka_vs_gym.fci.server import FCIServer
from franka_vs_gym.fci.urdf import robot_urdf

__all__ = ["ERROR_NAMES", "FCIRobot", "FCIServer", "error_bit", "robot_urdf"]
