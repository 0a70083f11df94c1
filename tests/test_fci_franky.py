"""franka-vs serve with franky (franky-control) as the client, lock-step mode: joint and Cartesian motions through
the robot's internal controller, and the Franka Hand (homing, move, grasp with and without an object)."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

# the clients run in their own processes (pylibfranka and franky cannot share one): only check it is installed
if importlib.util.find_spec("franky") is None:
    pytest.skip("franky is not installed (pip install -e '.[fci]')", allow_module_level=True)

from conftest import CLIENTS, loopback_host  # noqa: E402

from franka_vs_gym.fci import FCIServer  # noqa: E402

# a 3 cm block between the open fingers of the FER in its neutral pose
BLOCK = '<body name="block" pos="0.3069 0 0.49"><geom type="box" size="0.01 0.015 0.01" rgba="0.8 0.2 0.2 1"/></body>'




def run_client(script: str, *args: str) -> dict:
    r = subprocess.run([sys.executable, str(CLIENTS / script), *args], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _rot(quat_xyzw) -> np.ndarray:
    x, y, z, w = quat_xyzw
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_franky_joint_and_cartesian_motions():
    with FCIServer(loopback_host(23), lockstep=True, camera=False, verbose=False) as srv:
        out = run_client("franky_motions.py", srv.host)
        q_sim = srv.sim.get_position()
    # the joint motion ends on its target (the internal controller tracks within ~1e-5 rad)
    assert np.abs(np.array(out["q_after_joint"]) - out["q_target"]).max() < 1e-4
    # relative Cartesian motion: the offset is expressed in the end-effector frame
    p0, p1, p2 = (np.array(out[k]) for k in ("p0", "p1", "p2"))
    expected = p0 + _rot(out["quat0"]) @ np.array([0.05, -0.03, -0.04])
    assert np.abs(p1 - expected).max() < 1e-4
    assert np.abs(p2 - p0).max() < 1e-4  # and back to the absolute start pose
    assert abs(abs(np.dot(out["quat2"], out["quat0"])) - 1) < 1e-6  # orientation kept
    assert np.abs(np.array(out["state_q"]) - q_sim).max() < 1e-6


@pytest.mark.parametrize("block", [True, False])
def test_franky_gripper_move_and_grasp(block):
    with FCIServer(loopback_host(23), lockstep=True, camera=False, verbose=False,
                   extra_worldbody=BLOCK if block else "") as srv:
        out = run_client("franky_gripper.py", srv.host, "0.03")
    assert out["homing"] and out["move"] and out["open"]
    assert out["max_width"] == pytest.approx(0.08)
    assert out["width_after_move"] == pytest.approx(0.05, abs=1e-6)
    assert out["width_after_open"] == pytest.approx(0.08, abs=1e-6)
    if block:  # the fingers stop on the 3 cm block: grasped within the +-5 mm tolerance
        assert out["grasp"] and out["is_grasped"]
        assert out["width_after_grasp"] == pytest.approx(0.03, abs=2e-3)
    else:  # nothing between the fingers: they close fully and the grasp fails
        assert not out["grasp"] and not out["is_grasped"]
        assert out["width_after_grasp"] < 1e-3


def test_franky_ibvs_example_with_the_in_process_camera():
    """examples/fci_franky_ibvs.py: franky joint velocities, tag detection on the simulated wrist camera read from
    the in-process server; the corner error shrinks within 1.2 s of robot time (lock-step; converging fully takes
    about 1.7 s of robot time and 5 s of rendering)."""
    script = Path(__file__).resolve().parents[1] / "examples" / "fci_franky_ibvs.py"
    r = subprocess.run([sys.executable, str(script), "--lockstep", "--json", "--max-time", "1.2",
                        "--host", loopback_host(24)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    errors = [e for _, _, e in out["history"]]
    assert errors[0] > 20.0
    assert out["final_error_px"] < 0.3 * errors[0]


def test_franky_gripper_stop():
    with FCIServer(loopback_host(23), lockstep=True, camera=False, verbose=False) as srv:
        out = run_client("gripper_stop.py", srv.host)
    assert out["width_start"] == pytest.approx(0.08, abs=1e-6) and out["stop"]
    assert "aborted" in str(out["move_result"])  # the interrupted move is answered "aborted"
    assert 0.0 < out["width_after_stop"] < 0.08
    assert out["width_later"] == out["width_after_stop"]  # the fingers stay where they stopped


def _stalled_client(script: str, args: list[str], robot, stall: float, every: float = 0.25) -> dict:
    """Run the client ``script`` and stop its whole process for ``stall`` s every ``every`` s while the robot moves
    (SIGSTOP / SIGCONT, as a loaded machine stalls a client): its commands for those cycles come late. A sleep in
    franky's motion callback does not do it: measured, even 50 ms every 250 cycles left its control loop on time
    (no late command, no long period), so the test's premise was met only by chance."""
    import os
    import signal
    import threading
    import time

    p = subprocess.Popen([sys.executable, str(CLIENTS / script), *args], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)

    def stalls() -> None:
        while p.poll() is None:
            time.sleep(every)
            if robot.moving:
                try:
                    os.kill(p.pid, signal.SIGSTOP)
                    time.sleep(stall)
                    os.kill(p.pid, signal.SIGCONT)
                except ProcessLookupError:
                    return

    th = threading.Thread(target=stalls, daemon=True)
    th.start()
    try:
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.kill(p.pid, signal.SIGCONT)
            p.kill()
        th.join(5.0)
    assert p.returncode == 0, err[-3000:]
    return json.loads(out.strip().splitlines()[-1])


def test_real_time_elbow_motion_with_late_commands():
    """Real time, franky's elbow motion (the hand held, the elbow out by 0.3 rad) with a client process stopped for
    2.5 ms every 250 ms: commands that miss their cycle are dropped and the cycle extrapolated, as the FCI does, so
    libfranka's low-pass (against the state's O_T_EE_c and elbow_c) filters against where the motion is and the
    motion ends without a reflex. (Applied a cycle late instead, they tripped
    cartesian_motion_generator_joint_velocity_discontinuity: joint 1 at 25-120 rad/s^2.)"""
    # a tolerance of 200 missed cycles: a loaded test machine must not end the motion with the communication reflex.
    # The stalls make the client miss cycles only while the server keeps its 1 ms grid; on a machine loaded enough
    # that the server's own cycles overrun (the grid re-anchors, plant time falls behind) a stall can fit inside one
    # slow cycle and nothing is missed. Such a run does not exercise the case, so it is run again (at most 3 runs,
    # every one of which must end without a reflex and with the elbow out by 0.3 rad).
    missed = []
    for _ in range(3):
        with FCIServer(loopback_host(37), camera=False, verbose=False, max_missed_commands=200) as srv:
            out = _stalled_client("late_elbow_motion.py", [srv.host, "0", "0.3"], srv.robot, 0.0025)
            stats, dropped = srv.motion_stats, srv.late_commands
        assert out["raised"] is None, (out, stats)
        assert abs(out["elbow_end"] - out["elbow_start"] - 0.3) < 1e-3, out
        missed.append(out["long_periods"] + dropped)
        if missed[-1] >= 3:
            break
    assert missed[-1] >= 3, (missed, out, stats)  # the client did miss cycles

