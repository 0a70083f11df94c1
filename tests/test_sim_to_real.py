"""Sim to real through libfranka's protocol (franka_vs_gym.fci.sim_to_real, scripts/sim_to_real.py), short: one
seeded "real robot" (a lock-step ``franka-vs serve --truth`` server with a hidden payload, extra Coulomb friction
and a tilted mounting), a short designed excitation recorded by ``franka-vs excite``'s pylibfranka script,
``franka-vs fit --add auto``, and computed torque played through pylibfranka (franka_vs_gym.fci.deploy) with the
default, the calibrated and the true plant's model. The calibrated model must close most of the gap: an independent
check of the whole chain (a calibration that missed the payload, a runner that dropped the gravity difference, a
deployment whose held actions differed from the env's would all leave the gap open)."""

from __future__ import annotations

import importlib.util
import json
import os
import sys

import numpy as np
import pytest

if importlib.util.find_spec("pylibfranka") is None:
    pytest.skip("pylibfranka is not installed (pip install -e '.[fci]')", allow_module_level=True)

from conftest import loopback_host  # noqa: E402

from franka_vs_gym.fci import sim_to_real as s2r  # noqa: E402

NET = 247  # this file's loopback net (conftest.loopback_host)


def test_truth_and_true_model(tmp_path):
    """The seeded truths differ per seed and lie in their documented ranges; the true model carries them, and the
    served plant's armature."""
    from franka_vs_gym.model.config import ModelConfig

    a, b = s2r.truth_effects(0), s2r.truth_effects(1)
    assert a == s2r.truth_effects(0) and a != b
    e = {x["effect"]: x for x in a["effects"]}
    assert 0.7 <= e["payload"]["mass_kg"] <= 1.3 and 1.5 <= e["gravity_tilt"]["tilt_deg"] <= 2.5
    f = tmp_path / "truth.json"
    f.write_text(json.dumps(a))
    cfg = s2r.true_model(f)
    base = ModelConfig()
    assert cfg.payload.mass == pytest.approx(e["payload"]["mass_kg"])
    assert np.allclose(cfg.armature, np.asarray(base.robot.rotor_inertia))
    tilt = np.degrees(np.arccos(-cfg.gravity[2] / np.linalg.norm(cfg.gravity)))
    assert tilt == pytest.approx(e["gravity_tilt"]["tilt_deg"], abs=1e-6)
    assert s2r.gap_recovered(10.0, 2.0, 1.0) == pytest.approx(8 / 9)
    assert s2r.gap_recovered(1.5, 1.2, 1.0) is None  # the model is not what limits the controller


def _same_episode(env, policy, ep: dict) -> dict:
    """Play episode 10000 of env with policy, check it against the runner's episode ep step by step (500 steps, no
    failure, every step's tracking error within 2e-6 rad: float32 on the wire), close env; the last step's info."""
    obs, _ = env.reset(seed=10_000)
    errors = []
    while True:
        obs, _, term, trunc, info = env.step(policy.predict(obs)[0])
        errors.append(info["error"])
        if term or trunc:
            break
    env.close()
    assert len(errors) == ep["steps"] == 500 and ep["failure"] is None
    assert np.abs(np.array(ep["errors"]) - np.array(errors)).max() < 2e-6
    return info


def test_deployed_episode_is_the_env_episode(tmp_path):
    """The runner (pylibfranka, its own process: observation from RobotState, the action held 10 ms, the robot's
    rate limiter, the gravity of the policy's model less the robot's) on a server whose plant is the policy's model
    gives FrankaTorqueTracking-v0's episode: the same tracking error at every control step to float32 precision."""
    import subprocess
    import sys

    import gymnasium as gym

    from franka_vs_gym.fci import FCIServer
    from franka_vs_gym.model.config import ModelConfig
    from franka_vs_gym.policies import ComputedTorquePolicy

    base = ModelConfig()
    path = tmp_path / "model.json"  # the served plant: the robot's model and its motors' armature
    base.copy(armature=np.asarray(base.robot.rotor_inertia)).save(path)
    default_error = _default_error(loopback_host(NET + 2))  # the envs' default model (no armature) on that robot
    host = loopback_host(NET + 1)
    with FCIServer(host, lockstep=True, camera=False, verbose=False):
        r = subprocess.run([sys.executable, "-m", "franka_vs_gym.fci.deploy", host, "--policy", "computed_torque",
                            "--model", str(path), "--seeds", "10000"], capture_output=True, text=True, timeout=300,
                           env=s2r._env())
    assert r.returncode == 0, r.stderr[-2000:]
    ep = json.loads(r.stdout.strip().splitlines()[-1])["episodes"][0]
    env = gym.make("FrankaTorqueTracking-v0", action_scale="physical", model=str(path))
    policy = ComputedTorquePolicy(str(path))
    info = _same_episode(env, policy, ep)
    assert ep["rms_error"] == pytest.approx(info["rms_error"], rel=1e-3)
    # the same controller with the envs' default model tracks at least 5x worse on the robot with motors
    assert info["rms_error"] < 0.2 * default_error


def test_deployed_agent_episode_is_the_env_episode(tmp_path):
    """A residual torque agent through the runner (its base and the runner's gravity term on the agent's plant
    model, the network on the observation built from RobotState, the action held 10 ms) on a server whose plant is
    that model gives the agent's FrankaTorqueTracking-v0 episode step by step."""
    pytest.importorskip("stable_baselines3")
    import shutil
    import subprocess

    import gymnasium as gym

    from franka_vs_gym.envs.torque_agent import TorqueAgentPolicy
    from franka_vs_gym.fci import FCIServer
    from franka_vs_gym.model.config import ModelConfig
    from franka_vs_gym.policies import agent_path

    base = ModelConfig()
    path = tmp_path / "model.json"  # the served plant: the robot's model and its motors' armature
    base.copy(armature=np.asarray(base.robot.rotor_inertia)).save(path)
    src = agent_path("torque_tracking_fer")
    shutil.copy(src, tmp_path / "agent.zip")  # the shipped network, as an agent of that plant model
    meta = json.loads(src.with_suffix(".json").read_text())
    meta["env_kwargs"] = {"model": str(path)}
    (tmp_path / "agent.json").write_text(json.dumps(meta))
    host = loopback_host(NET + 5)
    with FCIServer(host, lockstep=True, camera=False, verbose=False):
        r = subprocess.run([sys.executable, "-m", "franka_vs_gym.fci.deploy", host, "--policy",
                            str(tmp_path / "agent.zip"), "--seeds", "10000"], capture_output=True, text=True,
                           timeout=300, env=s2r._env())
    assert r.returncode == 0, r.stderr[-2000:]
    ep = json.loads(r.stdout.strip().splitlines()[-1])["episodes"][0]
    agent = TorqueAgentPolicy.load(tmp_path / "agent.zip")
    env = gym.make("FrankaTorqueTracking-v0", action_scale="physical", model=str(path), clip_actions=True)
    agent.reset()
    _same_episode(env, agent, ep)
    # a mismatched --model is refused in one line (the agent's base is built on its own plant model)
    r = subprocess.run([sys.executable, "-m", "franka_vs_gym.fci.deploy", host, "--policy", str(tmp_path / "agent.zip"),
                        "--model", str(tmp_path / "other.json")], capture_output=True, text=True, timeout=120,
                       env=s2r._env())
    assert r.returncode == 2 and "trained on the plant model" in r.stderr, r.stderr


def _default_error(host):
    import subprocess
    import sys

    from franka_vs_gym.fci import FCIServer

    with FCIServer(host, lockstep=True, camera=False, verbose=False):
        r = subprocess.run([sys.executable, "-m", "franka_vs_gym.fci.deploy", host, "--policy", "computed_torque",
                            "--seeds", "10000"], capture_output=True, text=True, timeout=300, env=s2r._env())
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])["episodes"][0]["rms_error"]


@pytest.mark.slow
def test_calibrated_model_closes_the_gap_end_to_end(tmp_path):
    script = s2r.design_excitation(tmp_path / "excitation", duration=10.0, evaluations=100, time_budget=900)
    r = s2r.run_robot(0, tmp_path / "robot_0", loopback_host(NET), script, [10_000], ("computed_torque",))
    err = {m: r["runs"][f"computed_torque/{m}"]["rms_error"] for m in s2r.MODELS}
    assert "payload" in r["fit"]["effects"], r["fit"]
    assert err["default"] >= 5 * err["truth"], err  # the hidden plant costs the default model
    g = r["runs"]["computed_torque/gap_recovered"]
    assert g is not None and g >= 0.8, (g, err)
    assert not any(r["runs"][f"computed_torque/{m}"]["failures"] for m in s2r.MODELS)


def test_runner_errors_are_one_line():
    import subprocess
    import sys

    def run(*args):
        return subprocess.run([sys.executable, "-m", "franka_vs_gym.fci.deploy", *args], capture_output=True,
                              text=True, timeout=120, env=s2r._env())

    r = run(loopback_host(NET + 3), "--policy", "ibvs_ppo")  # a joint-velocity agent is no torque policy
    assert r.returncode == 2 and "FrankaIBVS-v0" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = run(loopback_host(NET + 3), "--seeds", "1")  # nobody serves there
    assert r.returncode == 1 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    r = run(loopback_host(NET + 3), "--seeds", "x")
    assert r.returncode == 2 and "--seeds" in r.stderr


def _descendants(pid: int) -> set[int]:
    """The pids of a process's descendants (Linux /proc)."""
    out: set[int] = set()
    todo = [pid]
    while todo:
        p = todo.pop()
        try:
            tasks = os.listdir(f"/proc/{p}/task")
        except OSError:
            continue
        for t in tasks:
            try:
                kids = [int(k) for k in open(f"/proc/{p}/task/{t}/children").read().split()]
            except OSError:
                continue
            out.update(kids)
            todo.extend(kids)
    return out


def _alive(pid: int) -> bool:
    try:
        state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc for the study's child processes")
def test_sigterm_ends_the_truth_server(tmp_path):
    """scripts/sim_to_real.py killed with SIGTERM while a truth server runs (here: idle, during the calibration)
    leaves no process behind (its server and its client processes end with it)."""
    import signal
    import subprocess
    import time
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, str(root / "scripts" / "sim_to_real.py"), "--out", str(tmp_path / "o"),
                             "--robots", "0", "--episodes", "1", "--duration", "6", "--evaluations", "10",
                             "--controllers", "computed_torque", "--host", loopback_host(NET + 4)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=s2r._env())
    kids: set[int] = set()
    try:
        for line in proc.stdout:  # the server is up and idle while the recording is calibrated
            if "calibrating" in line:
                break
        time.sleep(0.5)
        kids = _descendants(proc.pid)
        assert kids, "no child process while calibrating"
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(_alive(k) for k in kids):
            time.sleep(0.2)
        left = [k for k in kids if _alive(k)]
        assert not left, f"processes left after SIGTERM: {left}"
    finally:
        for k in kids | {proc.pid}:
            if _alive(k):
                os.kill(k, signal.SIGKILL)
