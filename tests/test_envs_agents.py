"""The agents of the joint-velocity envs (PBVS, eye-to-hand IBVS and PBVS, on the FER and the FR3): each loads through
the package's loading path and succeeds on held-out episodes it never saw; their training envs pass the checkers;
docs/envs.md's env x robot table is what scripts/envs_table.py writes from the sidecars."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path

import pytest

import franka_vs_gym
from franka_vs_gym.policies import AGENTS_DIR, load_agent, shipped_agents

ROOT = Path(__file__).resolve().parents[1]
VELOCITY_ENVS = ("FrankaPBVS-v0", "FrankaIBVSEyeToHand-v0", "FrankaPBVSEyeToHand-v0")


def _sidecar(name: str) -> dict:
    return json.loads((AGENTS_DIR / f"{name}.json").read_text())


#: the shipped agents of those envs (a new one is tested without editing this file)
NEW_AGENTS = [n for n in shipped_agents() if _sidecar(n).get("env_id") in VELOCITY_ENVS]


def _script(name: str):
    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.mark.slow
@pytest.mark.parametrize("name", NEW_AGENTS)
def test_agent_succeeds_on_held_out_episodes(name):
    """Three episodes (seeds 30000-30002: neither training, nor its stopping rule, nor the sidecar's test episodes
    20000-20099) on the robot the agent was trained for, through load_agent and franka_vs_gym.evaluate (what
    `franka-vs evaluate NAME` runs). An untrained network of the same shape succeeds in none (checked below)."""
    pytest.importorskip("stable_baselines3")
    meta = _sidecar(name)
    agent = load_agent(name)
    assert agent.env_id == meta["env_id"] and agent.env_kwargs.get("robot", "fer") == meta["robot"]
    kw = {"observation_type": "features", "action_type": "joint_velocity"} | agent.env_kwargs
    r = franka_vs_gym.evaluate(agent, agent.env_id, 3, 30_000, env_kwargs=kw)
    assert r["success_rate"] >= 2 / 3, r["failures"]


@pytest.mark.slow
def test_untrained_network_fails_the_same_check():
    """The check above can fail: the same policy class with its initial weights (the first new agent's recipe)
    reaches no goal in the same episodes."""
    pytest.importorskip("stable_baselines3")
    if not NEW_AGENTS:
        pytest.skip("no agent of the joint-velocity envs is shipped")
    from stable_baselines3 import PPO

    from franka_vs_gym.envs.sb3 import make_agent_vec_env
    from franka_vs_gym.envs.wrappers import AgentPolicy

    meta = _sidecar(NEW_AGENTS[0])
    venv = make_agent_vec_env(meta["env_id"], 1, meta["action_scale"], **meta["env_kwargs"])
    model = PPO("MlpPolicy", venv, seed=0, device="cpu", **meta["hyper_parameters"])
    venv.close()
    agent = AgentPolicy(model, meta["action_scale"], meta["env_id"], meta["env_kwargs"])
    kw = {"observation_type": "features", "action_type": "joint_velocity"} | meta["env_kwargs"]
    r = franka_vs_gym.evaluate(agent, meta["env_id"], 3, 30_000, env_kwargs=kw)
    assert r["success_rate"] == 0.0


@pytest.mark.parametrize("name", NEW_AGENTS)
def test_sidecar_schema_and_size(name):
    """ibvs_ppo.json's keys plus robot, the training curve and both evaluations (100 test episodes each); small zip."""
    meta = _sidecar(name)
    assert set(_sidecar("ibvs_ppo")) - {"evaluation"} <= set(meta)
    assert meta["robot"] in ("fer", "fr3") and meta["env_kwargs"].get("robot", "fer") == meta["robot"]
    assert meta["training_curve"] and all(0 <= r["success_rate"] <= 1 for r in meta["training_curve"])
    for key, robot in (("evaluation", meta["robot"]), ("evaluation_other_robot", {"fer": "fr3", "fr3": "fer"}[
            meta["robot"]])):
        assert meta[key]["n_episodes"] == 100 and meta[key]["robot"] == robot
    assert meta["train_cpu_s"] > 0 and meta["train_time_s"] > 0
    assert (AGENTS_DIR / f"{name}.zip").stat().st_size < 300_000


@pytest.mark.parametrize("env_id", VELOCITY_ENVS)
@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_training_env_passes_checkers(env_id, robot):
    """The agents' single training env (the flat vector, [-1, 1] actions) on each env and robot: Gymnasium's and
    SB3's checkers."""
    pytest.importorskip("stable_baselines3")
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check

    from franka_vs_gym.envs.wrappers import make_agent_env

    env = make_agent_env(env_id, 0.5, robot=robot)
    gym_check(env, skip_render_check=True)
    sb3_check(env)
    env.close()


def test_envs_table_is_generated():
    """docs/envs.md's env x robot table equals what scripts/envs_table.py writes (run it after changing a sidecar
    or docs/envs_scripted.json)."""
    mod = _script("envs_table")
    doc = (ROOT / "docs" / "envs.md").read_text()
    assert mod.replace_table(doc, mod.render()) == doc, "docs/envs.md's table is out of date: run " \
        "python scripts/envs_table.py"


def test_envs_table_follows_the_sidecars(tmp_path):
    """A changed evaluation in a sidecar changes the table (so the check above can fail), and an agent of an
    unregistered env is refused with its file named."""
    mod = _script("envs_table")
    for p in AGENTS_DIR.glob("*"):
        shutil.copy(p, tmp_path / p.name)
    base = mod.render(tmp_path)
    meta = json.loads((tmp_path / "ibvs_ppo.json").read_text())
    meta["evaluation"]["success_rate"] = 0.5
    (tmp_path / "ibvs_ppo.json").write_text(json.dumps(meta))
    changed = mod.render(tmp_path)
    assert changed != base and "0.50 of 100" in changed
    meta["env_id"] = "FrankaNothing-v0"
    (tmp_path / "ibvs_ppo.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="ibvs_ppo.json"):
        mod.render(tmp_path)


def test_time_to_solve_torque_task_calls_the_torque_recipe(tmp_path, monkeypatch, capsys):
    """A torque env id runs the torque recipe's train(env_id, robot, seed, out, ...) (here a stand-in that records
    its call and returns a sidecar) and reports its curve and evaluation; where the recipe file is absent the script
    says so in one line (exit status != 0) instead of training something else."""
    mod = _script("time_to_solve")
    fake = tmp_path / "train_torque.py"
    fake.write_text(
        "import json\n"
        "def train(env_id, robot, seed, out, eval_episodes=100, eval_seed=10000, threads=1, command=None, **kw):\n"
        "    json.dump([env_id, robot, seed, str(out), eval_episodes, eval_seed], open(CALL, 'w'))\n"
        "    return {'algo': 'ppo', 'timesteps': 4096, 'train_time_s': 12.5, 'train_cpu_s': 11.0,\n"
        "            'training_curve': [{'steps': 4096, 'success_rate': 0.5}],\n"
        "            'evaluation': {'success_rate': 0.97}, 'evaluation_other_robot': {'success_rate': 0.9}}\n"
        .replace("CALL", repr(str(tmp_path / "call.json"))))
    monkeypatch.setattr(mod, "TORQUE_RECIPE", fake)
    out = tmp_path / "result.json"
    assert mod.main(["--task", "FrankaVisualTorque-v0", "--robot", "fr3", "--seed", "3", "--test-seed", "500",
                     "--test-episodes", "7", "--json", str(out)]) == 0
    env_id, robot, seed, _, n, first = json.loads((tmp_path / "call.json").read_text())
    assert (env_id, robot, seed, n, first) == ("FrankaVisualTorque-v0", "fr3", 3, 7, 500)
    r = json.loads(out.read_text())
    assert r["solved"] and r["steps"] == 4096 and r["cpu_s"] == 11.0 and r["evaluation_other_robot"]
    monkeypatch.setattr(mod, "TORQUE_RECIPE", tmp_path / "absent.py")
    with pytest.raises(SystemExit) as e:
        mod.main(["--task", "FrankaTorqueTracking-v0"])
    assert "baselines/train_torque.py" in str(e.value.code)


@pytest.mark.parametrize("env_id", ["FrankaPBVS-v0", "FrankaPBVSEyeToHand-v0"])
def test_pose_layout_is_the_envs_pose_error(env_id):
    """servo_pose_vector's pose error (``--observation servo-pose-vector/1``) has the norms of the env's own PBVS
    error (translation, rotation: its success criterion), over a few steps of a moving arm; it starts with the
    servo vector."""
    import gymnasium as gym
    import numpy as np

    from franka_vs_gym.envs.wrappers import POSE_VECTOR_SIZE, VECTOR_SIZE, servo_pose_vector, servo_vector

    env = gym.make(env_id, observation_type="features")
    obs, _ = env.reset(seed=3)
    for k in range(4):
        v = servo_pose_vector(obs)
        assert v.shape == (POSE_VECTOR_SIZE,) and v.dtype == np.float32
        np.testing.assert_array_equal(v[:VECTOR_SIZE], servo_vector(obs))
        et, er = env.unwrapped._pose_error()
        assert et > 0.01 and er > 0.01  # far from the goal: a real comparison
        np.testing.assert_allclose(np.linalg.norm(v[VECTOR_SIZE:VECTOR_SIZE + 3]) / 10.0, et, rtol=1e-5)
        np.testing.assert_allclose(np.linalg.norm(v[VECTOR_SIZE + 3:VECTOR_SIZE + 6]) / 3.0, er, rtol=1e-5)
        obs, *_ = env.step(np.full(7, 0.3 * (-1) ** k, np.float32))
    env.close()


@pytest.mark.slow
def test_train_sb3_takes_env_and_robot(tmp_path):
    """baselines/train_sb3.py --env/--robot: a smoke run on an eye-to-hand env on the FR3 records the robot in the
    sidecar's env kwargs (so the agent loads onto that arm); a --robot that contradicts --env-kwargs is refused."""
    import subprocess
    import sys

    script = str(ROOT / "baselines" / "train_sb3.py")
    r = subprocess.run([sys.executable, script, "--smoke", "--algo", "ppo", "--env", "FrankaPBVSEyeToHand-v0",
                        "--robot", "fr3", "--out", str(tmp_path / "a"), "--tensorboard", "", "--eval-episodes", "0"],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    meta = json.loads((tmp_path / "a.json").read_text())
    assert meta["env_id"] == "FrankaPBVSEyeToHand-v0" and meta["robot"] == "fr3"
    assert load_agent(tmp_path / "a.zip").env_kwargs == {"robot": "fr3"}
    r = subprocess.run([sys.executable, script, "--robot", "fr3", "--env-kwargs", '{"robot": "fer"}', "--out",
                        str(tmp_path / "b")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "--robot fr3" in r.stderr and not (tmp_path / "b.zip").exists()


@pytest.mark.slow
@pytest.mark.parametrize("name", [n for n in NEW_AGENTS if "eye_to_hand" in n and n.endswith("fr3")][:1])
def test_time_to_solve_checks_are_evaluate_episodes(name):
    """time_to_solve's held-out checks (all episodes stepped together on the native vector env, eye-to-hand task
    logic in the batch) give each episode's success and length as franka_vs_gym.evaluate one by one, on the FR3."""
    pytest.importorskip("stable_baselines3")
    meta = _sidecar(name)
    agent = load_agent(name)
    r = _script("time_to_solve").evaluate_ibvs(agent.model, meta["env_id"], 4, 30_000, meta["action_scale"],
                                                meta["env_kwargs"], None, meta["observation_layout"])
    kw = {"observation_type": "features", "action_type": "joint_velocity"} | meta["env_kwargs"]
    ref = franka_vs_gym.evaluate(agent, meta["env_id"], 4, 30_000, env_kwargs=kw)
    assert [(e["success"], e["length"]) for e in r["episodes"]] == [(e["success"], e["length"])
                                                                    for e in ref["episodes"]]
