"""libfranka's example programs (examples/libfranka, pylibfranka) and franky's documented motions, each unmodified in
its own process against `franka-vs serve`, on the FER and the FR3, in lock-step and in real time.

Each must end as it ends on a real robot: exit code 0, no error in the robot state, the robot idle, and its own
measure of success within the example's tolerance (the motion generators return to their start; the impedance
controllers hold). Short durations where the example takes one (joint impedance ``--run-time``, Cartesian impedance
``--duration``); the motion generators run their full 8-10 s of robot time.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

if importlib.util.find_spec("pylibfranka") is None:
    pytest.skip("pylibfranka is not installed (pip install -e '.[fci]')", allow_module_level=True)

from conftest import loopback_host  # noqa: E402

from franka_vs_gym.fci import FCIServer  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "libfranka"


def run_example(name: str, host: str, *args: str, timeout: float = 300) -> dict:
    r = subprocess.run([sys.executable, str(EXAMPLES / f"{name}.py"), host, "--json", *args], capture_output=True,
                       text=True, timeout=timeout)
    assert r.returncode == 0, f"{name}: {r.stdout[-1500:]} {r.stderr[-3000:]}"
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert out["errors"] == "[]" and out["robot_mode"].endswith("Idle"), out
    return out


def check(out: dict) -> None:
    """The example's own success measure (see each example's docstring)."""
    name = out["example"]
    if name == "echo_robot_state":
        assert out["states"] == 100 and out["drift_rad"] < 1e-6
    elif name == "communication_test":
        assert out["success_mean"] >= 0.95 and out["drift_rad"] < 0.01  # the example's warning threshold
    elif name == "generate_joint_position_motion":
        assert out["worst_tracking_rad"] < 0.01
    elif name == "generate_joint_velocity_motion":
        assert out["return_error_rad"] < 1e-3 and out["worst_tracking_rad_s"] < 0.1
    elif name in ("generate_cartesian_pose_motion", "generate_cartesian_velocity_motion"):
        assert out["worst_tracking_m"] < 0.005 and out["return_error_m"] < 1e-3
    elif name == "joint_impedance_control":
        # K = 600..50 Nm/rad tracking a 0.25 m/s circle: a few degrees of lag, never a reflex
        assert out["worst_tracking_rad"] < 0.2 and out["torque_error_rms_nm"] < 1.0
    elif name == "cartesian_impedance_control":
        assert out["worst_drift_m"] < 1e-3
    elif name == "franky_examples":
        assert out["worst_error"] < 1e-3
        e = out["errors_by_motion"]
        assert abs(e["joint_velocity_motion_moved_rad"]) > 0.05 and e["cartesian_velocity_motion_moved_m"] > 0.01


LOCKSTEP = [("joint_impedance_control", ("--run-time", "0.5")), ("cartesian_impedance_control", ("--duration", "1")),
            ("echo_robot_state", ()), ("generate_joint_velocity_motion", ())]


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_examples_lockstep(robot):
    """The controllers and a motion generator on both robots, in lock-step (the joint-impedance example's gains, K
    = 600..50 Nm/rad and D = 50..15 Nm s/rad, stable on the plant with the motors' effective armature)."""
    with FCIServer(loopback_host(40), lockstep=True, camera=False, verbose=False, robot=robot) as srv:
        for name, args in LOCKSTEP:
            check(run_example(name, srv.host, *args))


@pytest.mark.slow
def test_all_motion_generators_and_franky_lockstep():
    """The remaining examples on the FER in lock-step: full 8-10 s motions, the communication test, franky."""
    with FCIServer(loopback_host(41), lockstep=True, camera=False, verbose=False) as srv:
        for name in ("generate_joint_position_motion", "generate_cartesian_pose_motion",
                     "generate_cartesian_velocity_motion", "communication_test"):
            check(run_example(name, srv.host))
    with FCIServer(loopback_host(41), lockstep=True, camera=False, verbose=False) as srv:
        check(run_example("franky_examples", srv.host))


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_examples_real_time(robot):
    """A subset in real time (the plant steps every millisecond of wall time): the state stream and the joint
    impedance controller, without a reflex (missed commands would raise communication_constraints_violation)."""
    with FCIServer(loopback_host(40), camera=False, verbose=False, robot=robot) as srv:
        check(run_example("echo_robot_state", srv.host))
        check(run_example("joint_impedance_control", srv.host, "--run-time", "0.5"))
