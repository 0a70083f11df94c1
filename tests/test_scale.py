"""Runs past one machine on Ray (the [scale] extra): distributed evaluation equal to the serial run, the workbench
over a folder of logs, one short RLlib training iteration on the batched vector env. A local Ray instance, 2 CPUs."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="the [scale] extra (Ray) is not installed")

import franka_vs_gym  # noqa: E402
from franka_vs_gym import scale  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _first_difference(a, b, path="") -> str:
    """Where two JSON values first differ, for the failure message."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in a:
            if k not in b:
                return f"{path}/{k}: missing"
            d = _first_difference(a[k], b[k], f"{path}/{k}")
            if d:
                return d
        return ""
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            d = _first_difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return ""
    return "" if _same(a, b) else f"{path}: {str(a)[:200]} != {str(b)[:200]}"


def _same(a, b):
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def test_distributed_evaluation_equals_the_serial_run(local_ray):
    """IBVS over seeds and randomised dynamics, 2 episodes per Ray task: the same summary and episodes."""
    from functools import partial

    from franka_vs_gym.envs.cli_evaluate import _policy_only, resolve_policy

    kw_in = {"time_limit": 2.0, "link_mass_range": [0.8, 1.2], "friction_scale_range": [0.5, 1.5]}
    policy, env_id, kw = resolve_policy("ibvs", None, kw_in)
    serial = franka_vs_gym.evaluate(policy, env_id, 5, seed=3, env_kwargs=kw)
    dist = scale.evaluate_distributed(partial(_policy_only, "ibvs", None, kw_in), env_id, 5, seed=3,
                                      env_kwargs=kw, chunk=2)
    assert _same(serial, dist)
    assert serial["success_rate"] > 0  # the episodes did something


def test_diagnose_folder_in_parallel_equals_serial_diagnose(local_ray, tmp_path):
    from franka_vs_gym.validation.hidden import make_hidden_effect_log
    from franka_vs_gym.validation.logs import save_log

    for i, effect in enumerate(("gravity_tilt", "none")):
        log, _ = make_hidden_effect_log(effect, 41 + i, duration=6.0, magnitude=1.5)
        save_log(log, tmp_path / f"{i}_{effect}.csv")
    res = scale.diagnose_folder(tmp_path)
    assert [Path(r["log"]).name for r in res] == ["0_gravity_tilt.csv", "1_none.csv"]
    # the serial reference in a fresh process, as each Ray worker is (this test process has run other tests before)
    code = ("import json, sys; from franka_vs_gym.validation import diagnose; "
            "print(json.dumps([diagnose(p).to_dict() for p in sys.argv[1:]]))")
    ref = subprocess.run([sys.executable, "-c", code, *[r["log"] for r in res]], capture_output=True, text=True,
                         check=True, timeout=600)
    for r, d in zip(res, json.loads(ref.stdout.strip().splitlines()[-1]), strict=True):
        assert _same(r["diagnosis"], d), _first_difference(r["diagnosis"], d)
    assert res[0]["diagnosis"]["verdict"] == "gravity_tilt"
    code = ("import json, sys; from franka_vs_gym import scale; "
            "print(json.dumps(scale.diagnose_folder(sys.argv[1], use_ray=False)))")
    serial = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, check=True,
                            timeout=600)
    serial = json.loads(serial.stdout.strip().splitlines()[-1])
    assert _same(serial, json.loads(json.dumps(res))), _first_difference(serial, json.loads(json.dumps(res)))
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no measurement logs"):
        scale.find_logs(tmp_path / "empty")


def test_rllib_ppo_iteration_on_the_batched_env(tmp_path):
    r = subprocess.run([sys.executable, str(ROOT / "baselines" / "train_rllib.py"), "--smoke", "--num-cpus", "2",
                        "--env-runners", "1", "--envs-per-runner", "4", "--out", str(tmp_path / "rl")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    summary = json.loads((tmp_path / "rl" / "summary.json").read_text())
    assert summary["vector_env"] == ["FrankaVectorEnv"]
    assert summary["history"][0]["env_steps_sampled"] > 0
    assert (tmp_path / "rl" / "checkpoint").is_dir()
