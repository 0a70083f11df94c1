"""Policies with the stable-baselines3 ``predict`` signature, on the same observations and actions as the
environments: classical visual servoing (IBVS, PBVS), torque control (computed torque, joint impedance), and the
shipped reinforcement-learning agent.

    from franka_vs_gym.policies import IBVSPolicy, load_agent
    policy = IBVSPolicy()                      # classical IBVS, joint-velocity actions (rad/s)
    agent = load_agent("ibvs_ppo")             # the shipped PPO agent (needs the [rl] extra)
    pixels = load_agent("ibvs_pixels")         # the agent that sees the camera image (env kwargs: pixels.env_kwargs)

The training scripts are ``baselines/train_sb3.py`` and ``baselines/train_pixels.py`` in the source tree (runnable
scripts, not an installed package).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from franka_vs_gym.policies.servo import IBVSEyeToHandPolicy, IBVSPolicy, PBVSEyeToHandPolicy, PBVSPolicy
from franka_vs_gym.policies.torque import ComputedTorquePolicy, JointImpedancePolicy

AGENTS_DIR = Path(__file__).resolve().parent / "agents"


def shipped_agents() -> list[str]:
    """Names of the agents shipped with the package (each a stable-baselines3 zip plus its JSON sidecar)."""
    return sorted(p.stem for p in AGENTS_DIR.glob("*.zip") if p.with_suffix(".json").is_file())


def agent_path(name: str) -> Path:
    """Path of a shipped agent's zip (e.g. ``agent_path("ibvs_ppo")``); a clear error for an unknown name."""
    p = AGENTS_DIR / f"{name}.zip"
    if not p.is_file():
        raise ValueError(f"unknown shipped agent {name!r}: shipped agents are {shipped_agents()}")
    return p


def load_agent(name_or_path: str | Path = "ibvs_ppo") -> Any:
    """An :class:`~franka_vs_gym.envs.wrappers.AgentPolicy` from a shipped agent's name or a zip path (a residual
    torque agent's sidecar gives a :class:`~franka_vs_gym.envs.torque_agent.TorqueAgentPolicy`)."""
    import json

    from franka_vs_gym.envs.wrappers import AgentPolicy

    p = Path(name_or_path)
    if p.suffix != ".zip" and not p.with_suffix(".zip").is_file():
        p = agent_path(str(name_or_path))
    meta = p.with_suffix(".json")
    if meta.is_file():
        from franka_vs_gym.envs.torque_agent import LAYOUTS, TorqueAgentPolicy

        try:
            layout = json.loads(meta.read_text()).get("observation_layout")
        except (ValueError, AttributeError):
            layout = None
        if layout in LAYOUTS.values():
            return TorqueAgentPolicy.load(p)
    return AgentPolicy.load(p)


def __getattr__(name: str) -> Any:
    if name == "AgentPolicy":  # the RL agent wrapper, imported on demand (its module needs gymnasium only)
        from franka_vs_gym.envs.wrappers import AgentPolicy

        return AgentPolicy
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["AGENTS_DIR", "AgentPolicy", "ComputedTorquePolicy", "IBVSEyeToHandPolicy", "IBVSPolicy",
           "JointImpedancePolicy", "PBVSEyeToHandPolicy", "PBVSPolicy", "agent_path", "load_agent", "shipped_agents"]
