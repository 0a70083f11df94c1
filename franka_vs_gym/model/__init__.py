"""Model of a Franka arm: robot descriptions (the FER, the FR3; :mod:`~franka_vs_gym.model.description`), the
configuration of one concrete robot (tool, payload, gravity, friction...; :class:`ModelConfig`), the friction law
(:mod:`~franka_vs_gym.model.friction`) and the pinocchio-backed dynamic model library (:class:`FrankaModel`)."""

from franka_vs_gym.model import params
from franka_vs_gym.model.config import Friction, ModelConfig, RigidBody, Tool, resolve_config
from franka_vs_gym.model.description import FER, FR3, ROBOTS, RobotDescription, register_robot, robot_description
from franka_vs_gym.model.franka_model import FrankaModel

__all__ = ["FER", "FR3", "ROBOTS", "FrankaModel", "Friction", "ModelConfig", "RigidBody", "RobotDescription", "Tool",
           "params", "register_robot", "resolve_config", "robot_description"]
