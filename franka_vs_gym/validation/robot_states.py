"""Former home of the robot-state readers and :class:`StateRecorder`, kept so that recording scripts written against
it keep working: everything now lives in :mod:`franka_vs_gym.validation.readers.robot_states`."""

from franka_vs_gym.validation.readers.fields import tool_from_state  # noqa: F401
from franka_vs_gym.validation.readers.robot_states import *  # noqa: F403
from franka_vs_gym.validation.readers.robot_states import StateRecorder  # noqa: F401
