#!/usr/bin/env python
"""libfranka's communication_test for pylibfranka: zero torques for 10 s while counting lost commands.

    python examples/libfranka/communication_test.py 127.0.0.1

The robot first moves to the ready pose (MotionGenerator, speed factor 0.5) with the default behaviour, then a
torque loop sends zero torques (gravity-free: the arm floats) for 10 s of robot time, sleeping 0.1 ms per cycle as
the example does, and reports the control_command_success_rate the robot measured (min, mean, max) and the robot
states the loop did not see. A mean below 0.95 is the example's warning threshold.
"""
import time

import numpy as np
import pylibfranka
from common import arguments, connect, move_to, report, run, set_collision_20, set_default_behavior


def main() -> None:
    args = arguments(__doc__)
    robot = connect(args.host)
    set_default_behavior(robot)
    started = time.monotonic()
    move_to(robot)
    set_collision_20(robot)
    q0 = np.array(robot.read_once().q)
    ms, counter, rates = 0, 0, []
    control = robot.start_torque_control()

    def cb(state, period):
        nonlocal ms, counter
        ms += round(period * 1000)
        counter += 1
        if state.control_command_success_rate > 0.0:
            rates.append(state.control_command_success_rate)
        time.sleep(100e-6)
        return pylibfranka.Torques([0.0] * 7), ms >= 10000

    run(control, cb)
    q1 = np.array(robot.read_once().q)
    report(args, robot, "communication_test", started, robot_time_s=ms / 1000, samples=counter,
           lost_states=max(ms - (counter - 1), 0),  # the first cycle's period is 0
           success_min=min(rates), success_mean=float(np.mean(rates)),
           success_max=max(rates), drift_rad=float(np.abs(q1 - q0).max()))


if __name__ == "__main__":
    main()
