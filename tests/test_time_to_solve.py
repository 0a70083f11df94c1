"""scripts/time_to_solve.py: its batched evaluation runs the same episodes as franka_vs_gym.evaluate, and bad
arguments are clear errors."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "time_to_solve.py"


def _script():
    spec = importlib.util.spec_from_file_location("time_to_solve", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_batched_evaluation_is_evaluate_episode_by_episode():
    """The shipped agent on 6 held-out seeds: the 6-robot vector evaluation gives each episode's success, length
    and time to converge exactly as franka_vs_gym.evaluate's one-by-one episodes."""
    pytest.importorskip("stable_baselines3")
    import franka_vs_gym
    from franka_vs_gym.policies import load_agent

    agent = load_agent("ibvs_ppo")
    tts = _script()
    # the scale the agent was trained with (rad/s of an output of 1): AgentPolicy.training_scale where the envs'
    # action spaces are normalized (AgentPolicy.action_scale then being the env's), else AgentPolicy.action_scale
    scale = getattr(agent, "training_scale", None)
    scale = float(agent.action_scale if scale is None else scale)
    r = tts.evaluate_ibvs(agent.model, "FrankaIBVS-v0", 6, 20_000, scale, {}, None)
    ref = franka_vs_gym.evaluate(agent, "FrankaIBVS-v0", 6, 20_000,
                                 env_kwargs={"observation_type": "features", "action_type": "joint_velocity"})
    for a, b in zip(r["episodes"], ref["episodes"], strict=True):
        assert a["success"] == b["success"] and a["length"] == b["length"], (a, b)
        assert np.isnan(a["time_to_converge"]) == np.isnan(b["time_to_converge"])
        if a["success"]:
            assert a["time_to_converge"] == b["time_to_converge"]
    assert len({e["length"] for e in r["episodes"]}) > 1  # the episodes differ: a comparison that can fail
    assert r["success_rate"] == ref["success_rate"]


@pytest.mark.parametrize("argv, match", [(["--goal", "1.5"], "--goal"), (["--n-envs", "0"], "--n-envs"),
                                         (["--task", "ibvs-pixels", "--eval-episodes", "0"], "--eval-episodes"),
                                         (["--task", "pixels"], "--task")])
def test_bad_arguments(argv, match, capsys):
    with pytest.raises(SystemExit) as e:
        _script().main(argv)
    assert e.value.code == 2
    assert match in capsys.readouterr().err
