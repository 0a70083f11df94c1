#!/usr/bin/env python
"""libfranka's echo_robot_state for pylibfranka: read and print 100 robot states, then stop.

    python examples/libfranka/echo_robot_state.py 127.0.0.1
"""
import time

import numpy as np
from common import arguments, connect, report


def main() -> None:
    args = arguments(__doc__)
    robot = connect(args.host)
    started = time.monotonic()
    count, q0 = 0, None
    while count < 100:
        state = robot.read_once()
        q0 = np.array(state.q) if q0 is None else q0
        if not args.json:
            print(f"t = {state.time.to_sec():.3f} s, q = {np.round(state.q, 4).tolist()}, "
                  f"tau_J = {np.round(state.tau_J, 3).tolist()}")
        count += 1
    report(args, robot, "echo_robot_state", started, states=count,
           drift_rad=float(np.abs(np.array(robot.read_once().q) - q0).max()))


if __name__ == "__main__":
    main()
