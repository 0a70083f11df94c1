#!/usr/bin/env python
"""libfranka's generate_cartesian_pose_motion for pylibfranka: the end effector swings on a 0.3 m arc in x-z.

    python examples/libfranka/generate_cartesian_pose_motion.py 127.0.0.1

Law: angle = pi/4 (1 - cos(pi/5 t)), x += 0.3 sin(angle), z += 0.3 (cos(angle) - 1) from the start pose, for 10 s
(the example's); the orientation is held.
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
    pose0 = list(robot.read_once().O_T_EE_d)
    radius, t, worst = 0.3, 0.0, 0.0
    control = robot.start_cartesian_pose_control(pylibfranka.ControllerMode.JointImpedance)

    def cb(state, period):
        nonlocal t, worst
        t += period
        worst = max(worst, float(np.linalg.norm(np.array(state.O_T_EE_d[12:15]) - np.array(state.O_T_EE[12:15]))))
        angle = math.pi / 4 * (1 - math.cos(math.pi / 5.0 * t))
        pose = list(pose0)
        pose[12] += radius * math.sin(angle)
        pose[14] += radius * (math.cos(angle) - 1)
        return pylibfranka.CartesianPose(pose), t > 10.0

    run(control, cb)
    end = np.array(robot.read_once().O_T_EE[12:15])
    report(args, robot, "generate_cartesian_pose_motion", started, robot_time_s=t, worst_tracking_m=worst,
           return_error_m=float(np.linalg.norm(end - np.array(pose0[12:15]))))


if __name__ == "__main__":
    main()
