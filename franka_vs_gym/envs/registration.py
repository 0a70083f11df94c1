"""Registration of the franka_vs_gym environments with Gymnasium (runs on ``import franka_vs_gym``).

Entry points are strings, so registering costs nothing: a task module is imported by ``gymnasium.make`` only.
Time limits are part of each task (``time_limit`` in seconds, truncation built in), so no ``max_episode_steps``
is registered; ``gymnasium.make(..., max_episode_steps=N)`` still adds Gymnasium's TimeLimit on top if wanted.
"""

from __future__ import annotations

import functools

import gymnasium as gym

ENVS: dict[str, str] = {
    "FrankaIBVS-v0": "franka_vs_gym.envs.ibvs:FrankaIBVSEnv",
    "FrankaPBVS-v0": "franka_vs_gym.envs.pbvs:FrankaPBVSEnv",
    "FrankaTorqueTracking-v0": "franka_vs_gym.envs.torque_tracking:FrankaTorqueTrackingEnv",
    "FrankaVisualTorque-v0": "franka_vs_gym.envs.visual_torque:FrankaVisualTorqueEnv",
    "FrankaIBVSEyeToHand-v0": "franka_vs_gym.envs.eye_to_hand:FrankaIBVSEyeToHandEnv",
    "FrankaPBVSEyeToHand-v0": "franka_vs_gym.envs.eye_to_hand:FrankaPBVSEyeToHandEnv",
}


def _vector_env(env_id: str, num_envs: int = 1, **kwargs):
    """The batched vector env; without the compiled plant (documented fallback) Gymnasium's SyncVectorEnv of the
    same environments, which gives the same results, slower."""
    from franka_vs_gym.sim import plant

    if plant.NATIVE:
        from franka_vs_gym.envs.vector import make_vector_env

        return make_vector_env(env_id, num_envs, **kwargs)
    kwargs.pop("nthread", None)
    kwargs.pop("task_logic", None)
    vec_kw = {k: kwargs.pop(k) for k in ("autoreset_mode", "copy") if k in kwargs}
    return gym.vector.SyncVectorEnv([functools.partial(gym.make, env_id, **kwargs) for _ in range(num_envs)],
                                    **vec_kw)


def register_envs() -> None:
    """Register every environment id (idempotent), with the batched vector env as its ``vector_entry_point``
    (``gymnasium.make_vec(id, num_envs=N)``; ``vectorization_mode="sync"`` or ``"async"`` still give Gymnasium's)."""
    for env_id, entry_point in ENVS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, disable_env_checker=False,
                         vector_entry_point=functools.partial(_vector_env, env_id))


register_envs()
