"""End-to-end tests of the franka-vs command and the README's promises."""

import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(*args, **kw):
    return subprocess.run([sys.executable, "-m", "franka_vs_gym.cli", *args], capture_output=True, text=True,
                          timeout=600, cwd=kw.get("cwd", ROOT))


def test_readme_test_command_is_what_ci_runs():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    blocks = re.findall(r"```bash\n(.*?)\n```", readme, re.S)
    assert len(blocks) >= 2
    test_cmd = next(b for b in blocks if "pytest" in b).strip()
    assert test_cmd in ci.splitlines()


def test_demo_torque_writes_outputs(tmp_path):
    out = tmp_path / "demo"
    # 2.7 s: the shortest duration whose trajectory stays within the FER's limits (0.6 s is refused, see
    # tests/test_faults.py)
    r = run("demo", "torque", "--duration", "2.7", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    assert (out / "joints_and_torques.png").stat().st_size > 10_000
    assert (out / "final_view.png").stat().st_size > 10_000
    assert (out / "motion.mp4").stat().st_size > 1_000
    metrics = json.loads((out / "metrics.json").read_text())
    assert len(metrics["rmse_q_rad"]) == 7
    assert max(metrics["rmse_q_rad"]) < 0.02


def test_demo_refuses_to_overwrite(tmp_path):
    out = tmp_path / "demo"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    r = run("demo", "--duration", "0.1", "--out", str(out), "--quiet", "--no-video")
    assert r.returncode == 2
    assert "not empty" in r.stderr
    assert (out / "keep.txt").read_text() == "precious"


def test_unknown_command_is_a_clear_error():
    r = run("frobnicate")
    assert r.returncode == 2
    assert "unknown command 'frobnicate'" in r.stderr


def test_bad_duration_is_a_clear_error(tmp_path):
    r = run("demo", "--duration", "-1", "--out", str(tmp_path / "x"), "--quiet")
    assert r.returncode == 2
    assert "--duration" in r.stderr


def test_demo_ibvs_with_detection_in_the_loop(tmp_path):
    out = tmp_path / "ibvs"
    r = run("demo", "ibvs", "--seed", "1", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    assert "converged" in r.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["converged"] and m["final_corner_error_px"] < 1.0 and m["features"] == "detect"
    assert (out / "camera.mp4").stat().st_size > 5_000
    assert (out / "servo.png").stat().st_size > 20_000


def test_demo_pbvs_ideal_features_no_video(tmp_path):
    out = tmp_path / "pbvs"
    r = run("demo", "pbvs", "--features", "ideal", "--no-video", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    m = json.loads((out / "metrics.json").read_text())
    assert m["converged"] and m["final_translation_error_m"] < 1e-3 and m["final_rotation_error_deg"] < 0.5
    assert not (out / "camera.mp4").exists()


def test_version_names_the_package_and_its_engines():
    from importlib.metadata import version

    import franka_vs_gym

    r = run("--version")
    assert r.returncode == 0, r.stderr
    line = r.stdout.strip()
    assert line.startswith(f"franka-vs {franka_vs_gym.__version__} ")
    assert f"mujoco {version('mujoco')}" in line and f"pinocchio {version('pin')}" in line
    assert version("franka_vs_gym") == franka_vs_gym.__version__  # the package metadata and the module agree
