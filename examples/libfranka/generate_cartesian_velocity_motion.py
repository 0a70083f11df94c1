#!/usr/bin/env python
"""libfranka's generate_cartesian_velocity_motion for pylibfranka: the end effector moves down-forward and back.

    python examples/libfranka/generate_cartesian_velocity_motion.py 127.0.0.1

Law: v = cycle * 0.1 / 2 (1 - cos(2 pi t / 4)) m/s along (cos 45 deg, 0, -sin 45 deg), cycle +1 for 4 s then -1
for 4 s (the example's), with its joint impedance (3000..2000 Nm/rad) and collision thresholds.
"""
import math
import time

import numpy as np
import pylibfranka
from common import arguments, connect, report, run


def main() -> None:
    args = arguments(__doc__)
    robot = connect(args.host)
    robot.set_joint_impedance([3000, 3000, 3000, 2500, 2500, 2000, 2000])
    lower_j, upper_j = [25.0, 25.0, 22.0, 20.0, 19.0, 17.0, 14.0], [35.0, 35.0, 32.0, 30.0, 29.0, 27.0, 24.0]
    lower_f, upper_f = [30.0, 30.0, 30.0, 25.0, 25.0, 25.0], [40.0, 40.0, 40.0, 35.0, 35.0, 35.0]
    robot.set_collision_behavior(lower_j, upper_j, lower_f, upper_f)  # (the C++ sets the same for both phases)
    started = time.monotonic()
    p0 = np.array(robot.read_once().O_T_EE[12:15])
    time_max, v_max, angle = 4.0, 0.1, math.pi / 4.0
    t, worst = 0.0, 0.0
    control = robot.start_cartesian_velocity_control(pylibfranka.ControllerMode.JointImpedance)

    def cb(state, period):
        nonlocal t, worst
        t += period
        worst = max(worst, float(np.linalg.norm(np.array(state.O_T_EE_d[12:15]) - np.array(state.O_T_EE[12:15]))))
        cycle = math.floor((-1.0) ** ((t - math.fmod(t, time_max)) / time_max))
        v = cycle * v_max / 2.0 * (1.0 - math.cos(2.0 * math.pi / time_max * t))
        finished = t > 2 * time_max
        if finished:
            v = 0.0
        return pylibfranka.CartesianVelocities([math.cos(angle) * v, 0.0, -math.sin(angle) * v, 0.0, 0.0, 0.0]), \
            finished

    run(control, cb)
    end = np.array(robot.read_once().O_T_EE[12:15])
    report(args, robot, "generate_cartesian_velocity_motion", started, robot_time_s=t, worst_tracking_m=worst,
           return_error_m=float(np.linalg.norm(end - p0)))


if __name__ == "__main__":
    main()
