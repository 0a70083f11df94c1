"""Build of the compiled part of franka_vs_gym: the plant's friction as a C callback for MuJoCo's step.

Everything else is in pyproject.toml. The extension is optional: without a C compiler the install still succeeds
and the plant applies its friction from Python before every physics step (same law, slower; see
franka_vs_gym.sim.plant and the README's "Scaling up").
"""

import os

from setuptools import Extension, setup


def _mujoco_include() -> list[str]:
    try:
        import mujoco
    except ImportError:  # a build without mujoco's headers: the extension is skipped (optional)
        return []
    return [os.path.join(os.path.dirname(mujoco.__file__), "include")]


# -ffp-contract=off: no fused multiply-adds, so the kernels' results are the same bits on every x86-64/arm64 build
setup(ext_modules=[Extension("franka_vs_gym.sim._plant",
                             ["franka_vs_gym/sim/_plant.c", "franka_vs_gym/sim/_task.c"],
                             depends=["franka_vs_gym/sim/_task.h"], include_dirs=_mujoco_include(),
                             extra_compile_args=["-O2", "-ffp-contract=off"], optional=True)])
