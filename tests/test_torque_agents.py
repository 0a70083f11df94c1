"""The shipped residual torque agents (franka_vs_gym.envs.torque_agent, baselines/train_torque.py): they load from
their name, play their env with physical torques and succeed on held-out episodes; their sidecars carry the recipe
and evaluation the issue asks for; the training wrapper and the shipped policy compute the same torque; and the
network earns its place: on the randomised plant it tracks better than its fixed base alone."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from franka_vs_gym.envs.torque_agent import LAYOUTS, ResidualBase, TorqueAgentPolicy, make_residual_env  # noqa: E402
from franka_vs_gym.policies import AGENTS_DIR, load_agent, shipped_agents  # noqa: E402

TORQUE_AGENTS = [n for n in shipped_agents()
                 if json.loads((AGENTS_DIR / f"{n}.json").read_text()).get("observation_layout") in LAYOUTS.values()]
BAR = {"fer": 0.9, "fr3": 0.8}  # the success bar on 100 held-out episodes


def _episodes(policy, env_id, robot, seeds, **kw):
    import gymnasium as gym

    env = gym.make(env_id, robot=robot, action_type="torque", action_scale="physical", clip_actions=True, **kw)
    out = []
    for s in seeds:
        obs, _ = env.reset(seed=s)
        policy.reset()
        while True:
            obs, _, term, trunc, info = env.step(policy.predict(obs)[0])
            if term or trunc:
                break
        out.append(info)
    env.close()
    return out


def test_the_four_torque_agents_ship():
    have = {(m["env_id"], m["robot"]) for m in (json.loads((AGENTS_DIR / f"{n}.json").read_text())
                                                for n in TORQUE_AGENTS)}
    assert {(e, r) for e in LAYOUTS for r in ("fer", "fr3")} <= have, have


@pytest.mark.parametrize("name", TORQUE_AGENTS)
def test_agent_loads_and_succeeds(name):
    meta = json.loads((AGENTS_DIR / f"{name}.json").read_text())
    for k in ("algo", "env_id", "robot", "structure", "timesteps", "seed", "train_time_s", "train_cpu_s", "command",
              "training_curve", "evaluation", "evaluation_other_robot", "evaluation_base_alone"):
        assert k in meta, k
    assert meta["evaluation"]["n_episodes"] == 100 and meta["evaluation"]["seed"] == 10_000
    agent = load_agent(name)
    assert isinstance(agent, TorqueAgentPolicy) and agent.env_id == meta["env_id"]
    infos = _episodes(agent, meta["env_id"], meta["robot"], range(10_000, 10_003))
    assert sum(bool(i.get("is_success")) for i in infos) >= 2, infos


def test_wrapper_and_policy_give_the_same_torque():
    """One torque for the network's action through the training wrapper and through the shipped policy."""
    name = next(n for n in TORQUE_AGENTS if n.startswith("torque_tracking_fer"))
    agent = load_agent(name)
    env = make_residual_env("FrankaTorqueTracking-v0", robot="fer")
    vec, _ = env.reset(seed=3)
    obs = env._obs  # (the dict observation behind the flat vector)
    agent.reset()
    tau_policy = agent.predict(obs)[0]
    a, _ = agent.model.predict(vec, deterministic=True)
    expected = env.base.combine(env.base.torque(obs), a)
    assert np.allclose(tau_policy, expected, atol=1e-4)
    assert not np.allclose(a, 0.0, atol=1e-3)  # (a trained residual: the comparison is not of two zeros)
    env.close()


def test_network_beats_its_base_on_the_randomised_plant():
    """The FER tracking agent was trained under the envs' dynamics randomisation: there it tracks better than its
    computed-torque base alone (the base's model lacks the undeclared payload, the masses, the friction)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location("train_torque", Path(__file__).resolve().parents[1] / "baselines"
                                                  / "train_torque.py")
    tt = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tt)
    agent = load_agent("torque_tracking_fer")
    base = ResidualBase("FrankaTorqueTracking-v0", None, "fer")

    class Base:
        def reset(self):
            base.reset()

        def predict(self, obs):
            return base.combine(base.torque(obs), np.zeros(7)).astype(np.float32), None

    seeds = range(20_000, 20_004)
    ea = [i.get("rms_error", 1.0) for i in _episodes(agent, "FrankaTorqueTracking-v0", "fer", seeds,
                                                      **tt.RANDOMIZATION)]
    eb = [i.get("rms_error", 1.0) for i in _episodes(Base(), "FrankaTorqueTracking-v0", "fer", seeds,
                                                      **tt.RANDOMIZATION)]
    assert np.mean(ea) < 0.7 * np.mean(eb), (ea, eb)


@pytest.mark.parametrize("name", ["torque_tracking_fer", "visual_torque_fr3"])
def test_franka_vs_evaluate_plays_a_shipped_torque_agent(name, capsys):
    """`franka-vs evaluate <torque agent>` plays it on its own env and robot with physical torque actions (it used
    to give the agent the servo agents' features observation and joint-velocity actions, and stopped with an error)."""
    from franka_vs_gym.cli import main as cli

    assert cli(["evaluate", name, "--episodes", "1", "--seed", "10000", "--quiet"]) == 0
    out = capsys.readouterr().out
    meta = json.loads((AGENTS_DIR / f"{name}.json").read_text())
    assert f"{name} on {meta['env_id']}" in out and "success rate 1.00" in out
