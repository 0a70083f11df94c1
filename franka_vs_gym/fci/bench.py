"""Benchmarks of the FCI server: lock-step round-trip rate with a pylibfranka client, server cost per cycle, and
the share of 1 kHz deadlines met in real-time mode (used by ``scripts/bench.py``)."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np


def _client(host: str, n: int) -> dict:
    r = subprocess.run([sys.executable, "-m", "franka_vs_gym.fci.bench_client", host, str(n)], capture_output=True,
                       text=True, timeout=300)
    if r.returncode != 0:
        raise RuntimeError(f"benchmark client failed: {r.stderr[-2000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def server_cycle_us(n: int = 3000, kind: str = "torque") -> float:
    """Best mean server-side cost of one lock-step cycle without networking (controller, plant step, state,
    encoding), us. ``kind``: "torque" (external torques), "joint" (joint position through the internal joint
    impedance), "cartesian" (a moving Cartesian pose through the joint impedance), "cartesian_impedance" (the same
    through the internal Cartesian impedance)."""
    from franka_vs_gym.fci.codec import MoveControllerMode as C
    from franka_vs_gym.fci.codec import MoveMotionGeneratorMode as G
    from franka_vs_gym.fci.codec import RobotCommand
    from franka_vs_gym.fci.robot import FCIRobot
    from franka_vs_gym.sim import FrankaSim

    modes = {"torque": (C.EXTERNAL_CONTROLLER, G.NONE), "joint": (C.JOINT_IMPEDANCE, G.JOINT_POSITION),
             "cartesian": (C.JOINT_IMPEDANCE, G.CARTESIAN_POSITION),
             "cartesian_impedance": (C.CARTESIAN_IMPEDANCE, G.CARTESIAN_POSITION)}
    robot = FCIRobot(FrankaSim(camera=False))
    robot.start_motion(*modes[kind])
    z = np.zeros(7)
    q0, T0 = robot.q_d.copy(), robot.O_T_EE_of(robot.q_d)
    best, k = np.inf, 0
    for _ in range(3):
        t = time.perf_counter()
        for i in range(n):
            s = 0.5 * (1 - np.cos(np.pi * k / (3 * n)))  # a smooth 5 cm / 0.1 rad move over the run
            q_c, T = q0.copy(), T0.copy()
            q_c[3] += 0.1 * s
            T[0, 3] += 0.05 * s
            robot.step(RobotCommand(i, q_c, z, T.ravel(order="F"), np.zeros(6), np.zeros(2), False, False, z, False))
            robot.fill_state().encode(i)
            k += 1
        best = min(best, (time.perf_counter() - t) / n * 1e6)
    if robot.reflex_detail:
        raise RuntimeError(f"benchmark motion tripped a reflex: {robot.reflex_detail}")
    return float(best)


def bench_fci(quick: bool = False, host: str = "127.0.31.1") -> dict[str, float]:
    """Lock-step rate (control cycles per wall second with pylibfranka) and the real-time deadline share."""
    from franka_vs_gym.fci.server import FCIServer

    n = 2000 if quick else 10000
    m = 1000 if quick else 3000
    out: dict[str, float] = {f"server cycle without networking, {kind}, us": server_cycle_us(m, kind)
                             for kind in ("torque", "joint", "cartesian", "cartesian_impedance")}
    with FCIServer(host, lockstep=True, camera=False, verbose=False) as srv:
        res = _client(srv.host, n)
    out["lock-step cycles per wall second (pylibfranka)"] = res["cycles"] / res["wall_s"]
    out["lock-step wall time for 10 s of robot time, s"] = 10.0 * res["wall_s"] / res["robot_s"]
    with FCIServer(host, lockstep=False, camera=False, verbose=False) as srv:
        res = _client(srv.host, n // 2)
        met, total, late = srv.deadlines_met, srv.deadlines_total, srv.late_cycles
    out["real-time: share of 1 kHz deadlines met (client command in time)"] = met / max(total, 1)
    out["real-time: cycles the server itself dropped"] = float(late)
    out["real-time: control_command_success_rate at the end"] = res["success_rate"]
    out["real-time: robot time / wall time"] = res["robot_s"] / res["wall_s"]
    return out


__all__ = ["bench_fci", "server_cycle_us"]
