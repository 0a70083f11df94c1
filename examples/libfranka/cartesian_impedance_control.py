#!/usr/bin/env python
"""libfranka's cartesian_impedance_control for pylibfranka: the hand is held at its start pose by a spring-damper.

    python examples/libfranka/cartesian_impedance_control.py 127.0.0.1 --translational-stiffness 150 \
        --rotational-stiffness 10

Law (the example's): ``tau = J^T (-K e - D J dq) + coriolis - tau_ext_hat_filtered`` with K = diag(k_t I3, k_r I3),
D = 2 sqrt(K) (damping ratio 1 for a unit mass), e the position error and the axis-angle orientation error of the
end effector against the start pose; collision thresholds 100 Nm / 100 N. The C++ example runs until it is stopped;
here it ends after ``--duration`` seconds (default 10) and reports how far the hand drifted.
"""
import time

import numpy as np
import pylibfranka
from common import arguments, connect, report, run
from scipy.spatial.transform import Rotation


def main() -> None:
    args = arguments(__doc__, translational_stiffness=(float, 150.0, "N/m"),
                     rotational_stiffness=(float, 10.0, "Nm/rad"), duration=(float, 10.0, "s"))
    kt, kr = args.translational_stiffness, args.rotational_stiffness
    stiffness = np.diag([kt] * 3 + [kr] * 3)
    damping = np.diag([2.0 * np.sqrt(kt)] * 3 + [2.0 * np.sqrt(kr)] * 3)
    robot = connect(args.host)
    model = robot.load_model()
    started = time.monotonic()
    T0 = np.array(robot.read_once().O_T_EE).reshape(4, 4).T
    position_d, orientation_d = T0[:3, 3], Rotation.from_matrix(T0[:3, :3])
    robot.set_collision_behavior([100.0] * 7, [100.0] * 7, [100.0] * 6, [100.0] * 6)
    t, worst = 0.0, 0.0
    control = robot.start_torque_control()

    def cb(state, period):
        nonlocal t, worst
        t += period
        J = np.array(model.zero_jacobian(state)).reshape(7, 6).T
        T = np.array(state.O_T_EE).reshape(4, 4).T
        error = np.zeros(6)
        error[:3] = T[:3, 3] - position_d
        error[3:] = (Rotation.from_matrix(T[:3, :3]) * orientation_d.inv()).as_rotvec()
        worst = max(worst, float(np.linalg.norm(error[:3])))
        tau = J.T @ (-stiffness @ error - damping @ (J @ np.array(state.dq))) + np.array(model.coriolis(state)) \
            - np.array(state.tau_ext_hat_filtered)
        return pylibfranka.Torques(tau.tolist()), t >= args.duration

    run(control, cb)
    report(args, robot, "cartesian_impedance_control", started, robot_time_s=t, worst_drift_m=worst)


if __name__ == "__main__":
    main()
