"""Model of the FER: published parameters, configuration (tool, payload, gravity, friction...) and the
pinocchio-backed dynamic model library."""

from franka_vs_gym.model import params
from franka_vs_gym.model.config import Friction, ModelConfig, RigidBody, Tool, resolve_config
from franka_vs_gym.model.franka_model import FrankaModel

__all__ = ["FrankaModel", "Friction", "ModelConfig", "RigidBody", "Tool", "params", "resolve_config"]
