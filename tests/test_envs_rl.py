"""Learning agents on the environments: wrappers, an SB3 training smoke run, the shipped agent, the evaluate CLI."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import franka_vs_gym
from franka_vs_gym.envs.wrappers import (
    VECTOR_SIZE,
    AgentPolicy,
    ScaledAction,
    ServoVectorObservation,
    make_agent_env,
    servo_vector,
)

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "franka_vs_gym" / "policies" / "agents" / "ibvs_ppo.zip"


def test_agent_env_passes_checkers_and_scales_actions():
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    env = make_agent_env("FrankaIBVS-v0", 0.5)
    assert env.action_space.shape == (7,) and np.all(env.action_space.high == 1.0)
    assert env.observation_space.shape == (VECTOR_SIZE,)
    gym_check(env, skip_render_check=True)
    sb3_check(env)
    env.reset(seed=0)
    for _ in range(3):
        env.step(np.full(7, 1.0, np.float32))
    dq = env.unwrapped.sim.get_velocity()
    np.testing.assert_allclose(dq, 0.5, atol=0.02)  # an action of 1 is 0.5 rad/s
    env.close()


def test_servo_vector_layout():
    env = gym.make("FrankaIBVS-v0")
    obs, _ = env.reset(seed=0)
    v = servo_vector(obs)
    assert v.dtype == np.float32 and v.shape == (VECTOR_SIZE,)
    e = obs["features"].astype(np.float64) - obs["features_desired"]
    np.testing.assert_allclose(v[:8], 4.0 * e, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(v[8:16]), np.linalg.norm(e) / (np.linalg.norm(e) + 0.005), rtol=1e-5)
    np.testing.assert_allclose(v[17:25], obs["features"])
    np.testing.assert_allclose(v[29:36], obs["q"])
    assert v[-1] == 1.0  # visible
    env.close()


def test_wrappers_reject_bad_input():
    env = gym.make("FrankaIBVS-v0", observation_type="image", image_width=48, image_height=36)
    with pytest.raises(ValueError, match="observation keys"):
        ServoVectorObservation(env)
    env.close()
    env = gym.make("FrankaIBVS-v0")
    with pytest.raises(ValueError, match="scale"):
        ScaledAction(env, 10.0)  # beyond dq_max
    w = ScaledAction(env, 0.5)
    with pytest.raises(ValueError, match="NaN"):
        w.action(np.full(7, np.nan))
    env.close()
    with pytest.raises(FileNotFoundError):
        AgentPolicy.load("/nonexistent/agent.zip")


def test_sb3_training_smoke(tmp_path):
    """A few hundred SAC steps through baselines/train_sb3.py, then the saved agent is loaded and evaluated."""
    out = tmp_path / "agent"
    cmd = [sys.executable, str(ROOT / "baselines" / "train_sb3.py"), "--smoke", "--out", str(out),
           "--tensorboard", str(tmp_path / "tb")]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "steps/s" in r.stdout and "success rate" in r.stdout
    assert (tmp_path / "agent.zip").is_file()
    meta = json.loads((tmp_path / "agent.json").read_text())
    assert meta["algo"] == "sac" and meta["env_id"] == "FrankaIBVS-v0"
    assert any((tmp_path / "tb").rglob("events.out.tfevents*"))
    # refuses to overwrite without --force
    r2 = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r2.returncode == 2 and "exists" in r2.stderr
    agent = AgentPolicy.load(out.with_suffix(".zip"))
    res = franka_vs_gym.evaluate(agent, "FrankaIBVS-v0", 1, seed=0)
    assert res["n_episodes"] == 1 and np.isfinite(res["mean_return"])


def test_ppo_training_smoke(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "baselines" / "train_sb3.py"), "--smoke", "--algo", "ppo",
                        "--out", str(tmp_path / "ppo"), "--tensorboard", ""], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "ppo.zip").is_file()


def test_shipped_agent_success_rate():
    """The agent shipped in franka_vs_gym/policies/agents reaches the goal on unseen episodes (seeds not used in
    training)."""
    assert SHIPPED.is_file(), f"missing shipped agent {SHIPPED}"
    assert SHIPPED.stat().st_size < 5e6
    agent = AgentPolicy.load(SHIPPED)
    res = franka_vs_gym.evaluate(agent, "FrankaIBVS-v0", 30, seed=50_000)
    assert res["success_rate"] >= 0.85, res["failures"]
    assert res["median_final_error"] < 0.01


def test_classical_ibvs_on_the_same_interface():
    """The scripted IBVS baseline and the agent run through the same evaluate() on the same episodes."""
    from franka_vs_gym.policies import IBVSPolicy

    res = franka_vs_gym.evaluate(IBVSPolicy(), "FrankaIBVS-v0", 5, seed=50_000)
    assert res["success_rate"] == 1.0 and res["mean_time_to_converge"] < 5.0


def test_cli_evaluate_zero_policy(tmp_path, capsys):
    from franka_vs_gym.cli import main

    out = tmp_path / "eval.json"
    rc = main(["evaluate", "zero", "--env", "FrankaIBVS-v0", "--episodes", "1", "--json", str(out), "--quiet",
               "--env-kwargs", '{"time_limit": 0.5}'])
    assert rc == 0
    assert "success rate 0.00" in capsys.readouterr().out
    data = json.loads(out.read_text())
    assert data["n_episodes"] == 1 and data["env_id"] == "FrankaIBVS-v0"
    assert main(["evaluate", "zero", "--episodes", "1", "--json", str(out)]) == 2  # exists, no --force
    assert main(["evaluate", "nonsense"]) == 2


def test_cli_evaluate_shipped_agent(capsys):
    from franka_vs_gym.cli import main

    rc = main(["evaluate", "ibvs_ppo", "--episodes", "2", "--seed", "60000", "--quiet"])  # by its shipped name
    assert rc == 0
    assert "success rate" in capsys.readouterr().out


def test_policies_are_package_data_and_baselines_is_not_a_package():
    import tomllib

    from franka_vs_gym.policies import agent_path, load_agent, shipped_agents

    assert "ibvs_ppo" in shipped_agents() and agent_path("ibvs_ppo") == SHIPPED
    assert load_agent("ibvs_ppo").env_id == "FrankaIBVS-v0"
    with pytest.raises(ValueError, match="unknown shipped agent 'nope'"):
        agent_path("nope")
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    assert cfg["packages"]["find"]["include"] == ["franka_vs_gym*"]
    assert cfg["package-data"]["franka_vs_gym.policies"] == ["agents/*.zip", "agents/*.json"]
    assert not (ROOT / "baselines" / "__init__.py").exists() and (ROOT / "baselines" / "train_sb3.py").is_file()


def test_cli_evaluate_scripted_baselines(capsys):
    from franka_vs_gym.cli import main

    assert main(["evaluate", "ibvs", "--episodes", "1", "--quiet"]) == 0
    assert "ibvs on FrankaIBVS-v0" in capsys.readouterr().out
    assert main(["evaluate", "pbvs", "--episodes", "1", "--quiet", "--env-kwargs",
                 '{"action_type": "cartesian_velocity"}']) == 0
    assert "success rate 1.00" in capsys.readouterr().out
    assert main(["evaluate", "computed-torque", "--episodes", "1", "--quiet", "--env-kwargs",
                 '{"time_limit": 0.5}']) == 0
    assert "FrankaTorqueTracking-v0" in capsys.readouterr().out
    assert main(["evaluate", "ibvs", "--episodes", "1", "--env-kwargs", '{"action_type": "torque"}']) == 2
