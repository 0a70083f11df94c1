"""Gymnasium environments of franka_vs_gym (registered on ``import franka_vs_gym``).

Ids: ``FrankaIBVS-v0``, ``FrankaPBVS-v0``, ``FrankaTorqueTracking-v0``, ``FrankaVisualTorque-v0``; see each task's
docstring (``gymnasium.spec(id).entry_point``) and docs/envs.md for their action/observation/reward tables.
"""

from __future__ import annotations

from typing import Any

from franka_vs_gym.envs.evaluate import evaluate
from franka_vs_gym.envs.registration import ENVS, register_envs


def bench(*args: Any, **kwargs: Any) -> dict:
    """Env steps/s of every environment next to its raw ``mujoco.mj_step`` cost; see
    :func:`franka_vs_gym.envs.benchmark.bench`."""
    from franka_vs_gym.envs.benchmark import bench as _bench

    return _bench(*args, **kwargs)


__all__ = ["ENVS", "bench", "evaluate", "register_envs"]
