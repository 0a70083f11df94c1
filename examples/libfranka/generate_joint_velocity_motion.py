#!/usr/bin/env python
"""libfranka's generate_joint_velocity_motion for pylibfranka: joints 4-7 turn forth and back, 2 x 4 s.

    python examples/libfranka/generate_joint_velocity_motion.py 127.0.0.1

Law: omega = cycle * 0.2 / 2 (1 - cos(2 pi t / 4)) rad/s on joints 4..7, cycle = +1 for the first 4 s and -1 for
the next 4 s (the example's), then the motion ends at rest where it started.
"""
import math
import time

import numpy as np
import pylibfranka
from common import arguments, connect, report, run, set_collision_20


def main() -> None:
    args = arguments(__doc__)
    robot = connect(args.host)
    set_collision_20(robot)
    started = time.monotonic()
    q0 = np.array(robot.read_once().q)
    time_max, omega_max = 4.0, 0.2
    t, worst = 0.0, 0.0
    control = robot.start_joint_velocity_control(pylibfranka.ControllerMode.JointImpedance)

    def cb(state, period):
        nonlocal t, worst
        t += period
        worst = max(worst, float(np.abs(np.array(state.dq_d) - np.array(state.dq)).max()))
        cycle = math.floor((-1.0) ** ((t - math.fmod(t, time_max)) / time_max))
        omega = cycle * omega_max / 2.0 * (1.0 - math.cos(2.0 * math.pi / time_max * t))
        finished = t > 2 * time_max
        return pylibfranka.JointVelocities([0.0, 0.0, 0.0] + [0.0 if finished else omega] * 4), finished

    run(control, cb)
    q1 = np.array(robot.read_once().q)
    report(args, robot, "generate_joint_velocity_motion", started, robot_time_s=t, worst_tracking_rad_s=worst,
           return_error_rad=float(np.abs(q1 - q0).max()))


if __name__ == "__main__":
    main()
