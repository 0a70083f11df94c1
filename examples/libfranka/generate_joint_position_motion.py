#!/usr/bin/env python
"""libfranka's generate_joint_position_motion for pylibfranka: joints 4, 5 and 7 swing by pi/4 and back in 10 s.

    python examples/libfranka/generate_joint_position_motion.py 127.0.0.1     # franka-vs serve, or 172.16.0.2

Law: q_c = q_start + pi/8 (1 - cos(pi/5 t)) on joints 4, 5, 7, for 10 s (the example's), with the joint impedance
controller and the collision thresholds of the example. Make sure there is room in front of the robot.
"""
import math
import time

import numpy as np
import pylibfranka
from common import arguments, connect, report, run, set_collision_20


def main() -> None:
    args = arguments(__doc__, duration=(float, 10.0, "motion time, s (the example's: 10)"))
    robot = connect(args.host)
    set_collision_20(robot)
    started = time.monotonic()
    q0 = np.array(robot.read_once().q_d)
    t, worst = 0.0, 0.0
    control = robot.start_joint_position_control(pylibfranka.ControllerMode.JointImpedance)

    def cb(state, period):
        nonlocal t, worst
        t += period
        worst = max(worst, float(np.abs(np.array(state.q_d) - np.array(state.q)).max()))
        delta = math.pi / 8 * (1 - math.cos(math.pi / 5.0 * t))
        q = q0.copy()
        q[[3, 4, 6]] += delta
        return pylibfranka.JointPositions(q.tolist()), t > args.duration

    run(control, cb)
    report(args, robot, "generate_joint_position_motion", started, robot_time_s=t, worst_tracking_rad=worst)


if __name__ == "__main__":
    main()
