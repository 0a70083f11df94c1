#!/usr/bin/env python
"""libfranka's force_control for pylibfranka: a PI force controller presses the bare flange on a table with the weight
of a 1 kg mass.

    franka-vs serve --tool none --q0 0 0.2 0 -2.2 0 2.4 0.7854 --table 0.2921 --lockstep
    python examples/libfranka/force_control.py 127.0.0.1

As the example demands, no end effector is mounted and the last joint rests on a horizontal rigid surface before it
starts: on the simulator ``--tool none`` and a raised table whose top touches the flange at the start pose (0.2919 m
above the base at this pose). The pose matters, on the robot too: the example's sensor bias keeps ``g(q0)``, so
along the arm's self-motion (the elbow turning about the shoulder-wrist line with the flange held by the table) the
change of gravity is not compensated. At the neutral pose, elbow up, that is an unstable equilibrium (gravity
stiffness -3.6 Nm/rad along the self-motion): the simulated arm, whose joint friction has no static part, turns
away and the example aborts after 4.7 s; at this reaching pose it is +2.4 Nm/rad and the flange stays within 0.05
mm (see docs/fci.md). Law (the example's): the torque sensor is biased at the start, ``tau_ext = tau_J -
g(q0) - (tau_J(0) - g(q0))``; the desired wrench is ``-9.81 m_d`` N along the base's z axis, ``tau_d = J^T F_d``; the
command is feed-forward plus PI on the torque error, ``tau = tau_d + k_p (tau_d - tau_ext) + k_i int(tau_d -
tau_ext) dt`` with k_p = 1, k_i = 2, and the mass ``m_d`` approaches 1 kg through a first-order filter of gain 0.001
per cycle (1 s time constant). Collision thresholds 100 Nm / 100 N. The example aborts when the flange moves more
than 1 cm from its start. ``franka::Robot::control`` low-passes every torque command at 100 Hz by default; the
pylibfranka loop here does the same (``common.lowpass``). The C++ example runs until it is stopped; here it finishes
after ``--duration`` s of robot time (default 10). The JSON summary reports the force the robot presses with,
estimated from the torque sensor as the example sees it (``F = (J^T)^+ tau_ext``, z, N), its mean over the last
second, the torque error of the PI loop, and the flange's largest distance from its start.
"""
import time

import numpy as np
import pylibfranka
from common import arguments, connect, lowpass, report, run, set_default_behavior

TARGET_MASS = 1.0  # kg
K_P = 1.0
K_I = 2.0
FILTER_GAIN = 0.001
MAX_DISTANCE = 0.01  # m: the example aborts beyond this distance from the start


def main() -> None:
    args = arguments(__doc__, duration=(float, 10.0, "robot time to press, s (the C++ example runs until stopped)"))
    robot = connect(args.host)
    set_default_behavior(robot)
    model = robot.load_model()
    robot.set_collision_behavior([100.0] * 7, [100.0] * 7, [100.0] * 6, [100.0] * 6)
    initial_state = robot.read_once()
    gravity = np.array(model.gravity(initial_state))  # the start's gravity, kept (the example's)
    initial_tau_ext = np.array(initial_state.tau_J) - gravity
    integral = np.zeros(7)
    desired_mass, t = 0.0, 0.0
    p0 = np.array(initial_state.O_T_EE[12:15])
    worst_distance, aborted = 0.0, ""
    forces: list[tuple[float, float]] = []
    err_last = np.zeros(7)
    started = time.monotonic()
    control = robot.start_torque_control()

    def cb(state, period):
        nonlocal integral, desired_mass, t, worst_distance, aborted, err_last
        t += period
        distance = float(np.linalg.norm(np.array(state.O_T_EE[12:15]) - p0))
        worst_distance = max(worst_distance, distance)
        if t > 0 and distance > MAX_DISTANCE:
            aborted = "Aborting; too far away from starting pose!"
            raise RuntimeError(aborted)
        J = np.array(model.zero_jacobian(state)).reshape(7, 6).T
        tau_ext = np.array(state.tau_J) - gravity - initial_tau_ext
        wrench = np.zeros(6)
        wrench[2] = desired_mass * -9.81
        tau_d = J.T @ wrench
        integral = integral + period * (tau_d - tau_ext)
        tau_cmd = tau_d + K_P * (tau_d - tau_ext) + K_I * integral
        desired_mass = FILTER_GAIN * TARGET_MASS + (1 - FILTER_GAIN) * desired_mass
        forces.append((t, float((np.linalg.pinv(J.T) @ tau_ext)[2])))
        err_last = tau_d - tau_ext
        tau_cmd = lowpass(tau_cmd, np.array(state.tau_J_d))  # franka::Robot::control's default filter
        return pylibfranka.Torques(tau_cmd.tolist()), t >= args.duration

    try:
        run(control, cb)
    except RuntimeError as e:  # the example prints the exception and ends (its motion is stopped)
        if not aborted:
            raise
        print(e)
        del control
        robot.stop()
    last = [f for s, f in forces if s > t - 1.0]
    report(args, robot, "force_control", started, robot_time_s=t, aborted=aborted,
           target_force_n=-9.81 * TARGET_MASS, force_n=forces[-1][1] if forces else 0.0,
           force_last_second_mean_n=float(np.mean(last)) if last else 0.0,
           torque_error_final_nm=float(np.abs(err_last).max()), worst_distance_m=worst_distance)


if __name__ == "__main__":
    main()
