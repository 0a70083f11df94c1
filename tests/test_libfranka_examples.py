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
import math
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

if importlib.util.find_spec("pylibfranka") is None:
    pytest.skip("pylibfranka is not installed (pip install -e '.[fci]')", allow_module_level=True)

from conftest import loopback_host  # noqa: E402

from franka_vs_gym.fci import FCIServer  # noqa: E402

# force_control: the bare flange resting on a raised table at a reaching pose (see the example's docstring)
FORCE_Q0 = [0.0, 0.2, 0.0, -2.2, 0.0, 2.4, math.pi / 4]
FORCE_TABLE = 0.2921  # m: 0.2 mm above the flange at FORCE_Q0 (0.29188 m), so the flange rests on it

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
    elif name == "force_control":
        # the example's own abort distance (1 cm) never reached; the rendered weight of 1 kg held (9.81 N)
        assert not out["aborted"] and out["worst_distance_m"] < 0.01
        assert abs(out["force_last_second_mean_n"] + 9.81) < 0.2, out
    elif name == "generate_elbow_motion":
        # the elbow out by pi/5 and back, the hand held at its start pose (the C++ example commands it unchanged)
        assert out["elbow_swing_error_rad"] < 1e-3 and out["elbow_return_error_rad"] < 1e-3, out
        assert out["worst_drift_m"] < 1e-3 and out["return_error_m"] < 1e-3 and out["robot_time_s"] >= 10.0, out
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
def test_elbow_motion_lockstep(robot):
    """libfranka's generate_elbow_motion (ported to franky: pylibfranka 0.21.3 sends no elbow) ends as on the robot:
    no reflex, the elbow out by pi/5 and back within 1 mrad, the hand within 1 mm of its start pose. The plant,
    sampled from the server's side (not what the client reports), turned joint 3 by pi/5 while its flange stayed
    put: the elbow command reached the joints (joint 3 through the IK's square system, the flip of joint 4 kept)."""
    with FCIServer(loopback_host(43), lockstep=True, camera=False, verbose=False, robot=robot) as srv:
        q3, flange, done = [], [], threading.Event()
        with srv.lock:
            q_start = srv.robot.q.copy()
            p_start = srv.robot.model.fMe(q_start)[:3, 3].copy()

        def sample():
            while not done.is_set():
                with srv.lock:
                    q = srv.robot.q.copy()
                q3.append(q[2])
                flange.append(np.linalg.norm(srv.robot.model.fMe(q)[:3, 3] - p_start))
                time.sleep(0.005)

        th = threading.Thread(target=sample, daemon=True)
        th.start()
        try:
            out = run_example("generate_elbow_motion", srv.host)
        finally:
            done.set()
            th.join()
    check(out)
    assert abs(max(q3) - q_start[2] - math.pi / 5) < 2e-3, (max(q3), q_start[2])
    assert max(flange) < 1e-3, max(flange)
    assert np.sign(out["q"][3]) == np.sign(q_start[3])


def wakeup_latency(duration: float = 0.3) -> float:
    """The worst overshoot of a 1 ms sleep over ``duration`` s (s): how late this machine wakes a process now."""
    worst, end = 0.0, time.perf_counter() + duration
    while time.perf_counter() < end:
        t0 = time.perf_counter()
        time.sleep(0.001)
        worst = max(worst, time.perf_counter() - t0 - 0.001)
    return worst


# Real time needs a machine that runs the client within the robot's tolerance of missed commands (more than 20
# cycles of 1 ms in a row without a command raise communication_constraints_violation, as on the robot, whose
# documentation asks for a real-time kernel). The test states that precondition: it measures how late a 1 ms sleep
# wakes up first and skips above half the tolerance; a run that ends in communication_constraints_violation is the
# machine's load (the robot's own verdict on a slow client PC) and is reported as a skip with its numbers; any other
# failure fails. Cycles the server itself could not run in time are dropped, not blamed on the client
# (FCIServer.motion_stats).
MAX_WAKEUP_LATENCY = 0.010  # s


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_examples_real_time(robot):
    """A subset in real time (the plant steps every millisecond of wall time): the state stream and the joint
    impedance controller, without a reflex (missed commands would raise communication_constraints_violation)."""
    import os

    latency = wakeup_latency()
    load = os.getloadavg()[0]
    if latency > MAX_WAKEUP_LATENCY:
        pytest.skip(f"load precondition not met: a 1 ms sleep wakes up to {latency * 1e3:.1f} ms late here (load "
                    f"{load:.1f} on {os.cpu_count()} cores; real time needs < {MAX_WAKEUP_LATENCY * 1e3:.0f} ms)")
    with FCIServer(loopback_host(40), camera=False, verbose=False, robot=robot) as srv:
        for name, args in (("echo_robot_state", ()), ("joint_impedance_control", ("--run-time", "0.5"))):
            try:
                check(run_example(name, srv.host, *args))
            except AssertionError as e:
                if "communication_constraints_violation" in str(e):
                    pytest.skip(f"machine too loaded for real time during {name}: {srv.motion_stats[-1:]} "
                                f"(load {os.getloadavg()[0]:.1f})")
                raise
        stats = srv.motion_stats
    # every motion ran and ended by itself; the statistics count what the server saw
    assert stats and all(st["status"] == "success" for st in stats), stats
    assert all(st["max_missed_in_row"] <= 20 and st["cycles"] > 0 for st in stats), stats
    print(f"real time, {robot}: wake-up latency {latency * 1e3:.1f} ms, load {load:.1f}; motions: {stats}")


def table_force(srv: FCIServer) -> tuple[float, float]:
    """(simulated time, total normal force of the plant's contacts with the table, N): MuJoCo's own contact forces,
    independent of the torque sensor the example's estimate rests on."""
    import mujoco

    with srv.lock:
        m, d = srv.sim.world.model, srv.sim.world.data
        table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
        f6, total = np.zeros(6), 0.0
        for i in range(d.ncon):
            c = d.contact[i]
            if table in (c.geom1, c.geom2):
                mujoco.mj_contactForce(m, d, i, f6)
                total += f6[0]
        return float(d.time), total


@pytest.mark.parametrize("robot", ["fer", "fr3"])
def test_force_control_lockstep(robot):
    """libfranka's force_control presses the bare flange on a rigid table with the weight of 1 kg: the example's own
    estimate (torque sensor through the Jacobian) settles at -9.81 N, the flange stays within the example's 1 cm,
    and the plant's contact force with the table (MuJoCo's, independent of the torque sensor) is 9.81 N within 5 %
    (measured 9.76 N on the FER; at the start the idle robot rests on the table with 0.8 N, which the example's
    sensor bias removes)."""
    with FCIServer(loopback_host(42), lockstep=True, camera=False, verbose=False, robot=robot, tool="none",
                   table_height=FORCE_TABLE, q0=FORCE_Q0) as srv:
        t_start, f_start = table_force(srv)
        assert f_start < 5.0  # resting, not pressing
        samples, done = [], threading.Event()

        def sample():
            while not done.is_set():
                samples.append(table_force(srv))
                time.sleep(0.01)

        th = threading.Thread(target=sample, daemon=True)
        th.start()
        try:
            out = run_example("force_control", srv.host, "--duration", "6")
        finally:
            done.set()
            th.join()
    check(out)
    t_end = t_start + out["robot_time_s"]
    last = [f for t, f in samples if t_end - 1.0 < t < t_end - 0.01]
    assert len(last) > 5
    assert abs(np.mean(last) - 9.81) < 0.5, (f_start, np.mean(last))
