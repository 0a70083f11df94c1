"""The logic of the speed check (scripts/bench.py --check, scripts/bench_check.py), without timing anything: a
regression beyond the tolerance is named, one within it is not, a rerun clears a figure only when its second
measurement is within the tolerance, and a clone without the previous commit says so instead of failing. The
speed figures themselves are measured by the check, CI's own step after the tests, not in the test run."""

from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bc():
    spec = importlib.util.spec_from_file_location("bench_check", ROOT / "scripts" / "bench_check.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


BASE = {"env step / raw physics: FrankaIBVS-v0": 1.05, "vector env N=64 (1 thread) / raw physics: X-v0": 1.10,
        "serve commands/s": 6000.0}


def test_a_30_percent_regression_is_named_and_a_3_percent_one_is_not(bc):
    now = {"env step / raw physics: FrankaIBVS-v0": 1.05 * 1.03,  # 3 % more cost
           "vector env N=64 (1 thread) / raw physics: X-v0": 1.10 * 1.30,  # 30 % more cost
           "serve commands/s": 6000.0 / 1.03}  # a rate 3 % lower
    rows = bc.compare(BASE, now, bc.TOLERANCE, {"serve commands/s"})
    worse = [r["figure"] for r in rows if r["worse"]]
    assert worse == ["vector env N=64 (1 thread) / raw physics: X-v0"]
    by = {r["figure"]: r for r in rows}
    assert by["env step / raw physics: FrankaIBVS-v0"]["change"] == pytest.approx(0.03)
    assert by["vector env N=64 (1 thread) / raw physics: X-v0"]["change"] == pytest.approx(0.30)
    # a rate is a cost inverted: 30 % fewer commands per second is 43 % more time per command
    rows = bc.compare(BASE, {"serve commands/s": 6000.0 * 0.7}, bc.ABS_TOLERANCE, {"serve commands/s"})
    assert rows[0]["worse"] and rows[0]["change"] == pytest.approx(1 / 0.7 - 1)
    # faster is never a regression; the table names the worse figure
    rows = bc.compare(BASE, {"env step / raw physics: FrankaIBVS-v0": 0.5}, bc.TOLERANCE)
    assert not rows[0]["worse"]
    table = bc.format_rows(bc.compare(BASE, now, bc.TOLERANCE, {"serve commands/s"}), bc.TOLERANCE)
    assert "| vector env N=64 (1 thread) / raw physics: X-v0 | 1.1 | 1.43 | +30.0% | WORSE |" in table


def test_new_or_unmeasured_figures_are_reported_not_failed(bc):
    rows = bc.compare(BASE, {"a new figure": 2.0, "env step / raw physics: FrankaIBVS-v0": math.nan}, 0.15)
    assert not any(r["worse"] for r in rows)
    assert [r["note"] for r in rows] == ["no baseline (new figure)", "not measured"]


def test_one_rerun_before_a_regression_is_declared(bc):
    calls = []
    noisy = {"a": [1.5, 1.02], "b": [1.5, 1.4], "c": [1.0]}  # a: slow once (load), b: really slower, c: fine

    def measure(names):
        calls.append(list(names))
        return {n: noisy[n][len([c for c in calls if n in c]) - 1] for n in names}

    rows = bc.check_with_rerun(measure, ["a", "b", "c"], {"a": 1.0, "b": 1.0, "c": 1.0}, 0.15, log=lambda s: None)
    assert calls == [["a", "b", "c"], ["a", "b"]]  # only the figures beyond the tolerance are measured again
    by = {r["figure"]: r for r in rows}
    assert not by["a"]["worse"] and by["a"]["now"] == 1.02 and by["a"]["rerun"]
    assert by["b"]["worse"] and by["b"]["now"] == 1.4  # the better of its two measurements, still 40 % worse
    assert not by["c"]["worse"] and not by["c"]["rerun"]


def test_a_clone_without_the_previous_commit_says_so(bc, tmp_path, monkeypatch):
    repo = tmp_path / "repo"
    repo.mkdir()
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false"]
    subprocess.run(["git", "init", "-q", str(repo)], check=True)
    (repo / "f").write_text("x")
    subprocess.run([*git, "add", "f"], cwd=repo, check=True)
    subprocess.run([*git, "commit", "-q", "-m", "first"], cwd=repo, check=True)
    monkeypatch.setattr(bc, "ROOT", repo)
    path, msg = bc.previous_tree("HEAD^", tmp_path / "prev", log=lambda s: None)
    assert path is None and "no commit 'HEAD^' to compare with" in msg and "first commit" in msg
    monkeypatch.setattr(bc, "ROOT", tmp_path / "not-a-repo")
    (tmp_path / "not-a-repo").mkdir()
    path, msg = bc.previous_tree("HEAD^", tmp_path / "prev", log=lambda s: None)
    assert path is None and "not a git checkout" in msg


def test_baselines_cover_every_registered_env(bc):
    """The stored baselines name every registered env's step and vector-env figure, so a new env cannot be left
    out of the check (refresh with python scripts/bench.py --refresh-baselines)."""
    import franka_vs_gym  # noqa: F401
    from franka_vs_gym.envs.registration import ENVS

    figures = json.loads(bc.BASELINES.read_text())["figures"]
    for env_id in ENVS:
        assert f"env step / raw physics: {env_id}" in figures
        assert f"vector env N=64 (1 thread) / raw physics: {env_id}" in figures
    assert set(figures) == set(bc.ratio_figures())
    assert all(0.5 < v < 10 for v in figures.values())


def test_check_mode_refuses_an_existing_json_file(tmp_path):
    out = tmp_path / "r.json"
    out.write_text("{}")
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "bench.py"), "--check", "--json", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode != 0 and "exists" in r.stderr and out.read_text() == "{}"


def test_wall_time_is_not_judged_on_an_overloaded_machine(bc):
    wall, cpu = "diagnose 30 s at 1 kHz (whole process): wall s", "diagnose 30 s at 1 kHz (whole process): CPU s"
    base, now = {wall: 10.0, cpu: 7.0}, {wall: 20.0, cpu: 9.8}
    rows = bc.judge_wall(bc.compare(base, now, bc.ABS_TOLERANCE), max_load=4.5, cpus=2)
    assert [r["worse"] for r in rows] == [False, True]  # the CPU time (40 % more) is judged up to 3 per CPU
    assert rows[0]["note"] == "not judged: load 4.5 on 2 CPUs"
    rows = bc.judge_wall(bc.compare(base, now, bc.ABS_TOLERANCE), max_load=14.0, cpus=2)
    assert [r["worse"] for r in rows] == [False, False]
    rows = bc.judge_wall(bc.compare(base, now, bc.ABS_TOLERANCE), max_load=1.5, cpus=2)
    assert [r["worse"] for r in rows] == [True, True]
