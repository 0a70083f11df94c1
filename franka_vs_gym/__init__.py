"""franka_vs_gym: a simulator of Franka arms (the Franka Emika Robot, FER, by default; the Franka Research 3, FR3)
for visual servoing, torque control and RL.

Importing the package registers its Gymnasium environments.
"""

import os as _os

# Headless rendering: MuJoCo picks its OpenGL backend when first imported, so choose EGL before that on a machine
# with no display (users can override with MUJOCO_GL=osmesa or glfw).
if "MUJOCO_GL" not in _os.environ and not _os.environ.get("DISPLAY"):
    _os.environ["MUJOCO_GL"] = "egl"
    _os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

__version__ = "0.1.0"

from franka_vs_gym.envs import registration as _registration  # noqa: E402,F401  (registers the Gymnasium ids)
from franka_vs_gym.envs.evaluate import evaluate  # noqa: E402
from franka_vs_gym.model import FrankaModel, ModelConfig  # noqa: E402
from franka_vs_gym.sim import FrankaSim  # noqa: E402

__all__ = ["FrankaModel", "FrankaSim", "ModelConfig", "__version__", "evaluate"]
