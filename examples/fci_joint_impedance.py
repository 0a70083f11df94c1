#!/usr/bin/env python
"""Joint impedance control with pylibfranka: the same script drives the simulator and the real robot.

    franka-vs serve --lockstep &                     # the simulated FER on 127.0.0.1
    python examples/fci_joint_impedance.py 127.0.0.1
    python examples/fci_joint_impedance.py 172.16.0.2   # the real robot (FCI activated in Desk)

A gravity-free torque controller (the robot adds gravity) renders a joint spring-damper around a minimum-jerk
trajectory from the current pose to a target, with Coriolis compensation from the robot's model
(``robot.load_model()``), then holds the target. Time comes from the robot state, so the script behaves the same at
any speed of the lock-step simulator. ``--json`` prints the trajectory for tests and comparisons.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pylibfranka

STIFFNESS = np.array([600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0])  # Nm/rad
DAMPING = 2.0 * np.sqrt(STIFFNESS * np.array([1.0, 1.0, 0.5, 0.5, 0.05, 0.05, 0.01]))  # Nm s/rad


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("host", nargs="?", default="127.0.0.1", help="robot (or simulator) address")
    ap.add_argument("--target", type=float, nargs=7, default=[0.3, -0.5, 0.2, -2.0, 0.1, 1.6, 0.9],
                    help="target joint position, rad")
    ap.add_argument("--duration", type=float, default=2.0, help="motion time, s (then 0.5 s of holding)")
    ap.add_argument("--json", action="store_true", help="print the measured trajectory as JSON")
    args = ap.parse_args()

    robot = pylibfranka.Robot(args.host, pylibfranka.RealtimeConfig.kIgnore)
    robot.set_collision_behavior([20.0] * 7, [40.0] * 7, [20.0] * 6, [40.0] * 6)
    model = robot.load_model()
    q_goal = np.array(args.target)
    control = robot.start_torque_control()
    t, q_start, log = 0.0, None, []
    total = args.duration + 0.5
    while True:
        state, period = control.readOnce()
        t += period.to_sec()
        q, dq = np.array(state.q), np.array(state.dq)
        if q_start is None:
            q_start = q.copy()
        s = min(t / args.duration, 1.0)
        blend = 10 * s**3 - 15 * s**4 + 6 * s**5
        dblend = (30 * s**2 - 60 * s**3 + 30 * s**4) / args.duration if s < 1.0 else 0.0
        q_d = q_start + blend * (q_goal - q_start)
        dq_d = dblend * (q_goal - q_start)
        tau = STIFFNESS * (q_d - q) + DAMPING * (dq_d - dq) + np.array(model.coriolis(state))
        cmd = pylibfranka.Torques(tau.tolist())
        cmd.motion_finished = t >= total
        control.writeOnce(cmd)
        log.append([t, *q.tolist()])
        if t >= total:
            break
    final = np.array(robot.read_once().q)
    error = float(np.abs(final - q_goal).max())
    if args.json:
        print(json.dumps({"log": log, "final": final.tolist(), "goal": q_goal.tolist(), "error": error}))
    else:
        print(f"reached the target within {error * 1e3:.2f} mrad after {t:.2f} s of robot time ({len(log)} cycles)")


if __name__ == "__main__":
    main()
