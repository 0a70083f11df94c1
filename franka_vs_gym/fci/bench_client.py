"""A pylibfranka client for the FCI benchmarks (run as its own process: ``python -m franka_vs_gym.fci.bench_client
HOST N``): N cycles of gravity-free torque control with a light joint damping, timed inside the client. Prints JSON
with the wall time of the control loop, the robot time it covered and the last control_command_success_rate."""

from __future__ import annotations

import json
import sys
import time


def main() -> None:
    import pylibfranka

    host, n = sys.argv[1], int(sys.argv[2])
    robot = pylibfranka.Robot(host, pylibfranka.RealtimeConfig.kIgnore)
    control = robot.start_torque_control()
    state, _ = control.readOnce()
    t_start, robot_t0 = time.perf_counter(), state.time.to_sec()
    for i in range(n):
        tau = pylibfranka.Torques([-0.5 * v for v in state.dq])
        tau.motion_finished = i == n - 1
        control.writeOnce(tau)
        if i < n - 1:
            state, _ = control.readOnce()
    wall = time.perf_counter() - t_start
    print(json.dumps({"cycles": n, "wall_s": wall, "robot_s": state.time.to_sec() - robot_t0,
                      "success_rate": state.control_command_success_rate}))


if __name__ == "__main__":
    main()
