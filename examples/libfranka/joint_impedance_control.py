#!/usr/bin/env python
"""libfranka's joint_impedance_control for pylibfranka: a joint spring-damper tracks a 5 cm circle of the hand.

    python examples/libfranka/joint_impedance_control.py 127.0.0.1

First the robot moves to the ready pose (the examples' MotionGenerator at speed factor 0.5). Then a torque loop runs
the example's law ``tau = K (q_d - q) - D dq + coriolis`` with its gains, K = 600, 600, 600, 600, 250, 150, 50
Nm/rad and D = 50, 50, 50, 50, 30, 25, 15 Nm s/rad, its torque-rate limit (1000 Nm/s against the last command,
``tau_J_d``) and collision thresholds, while the desired hand position runs on a circle of radius 0.05 m in the y-z
plane at up to 0.25 m/s (2 s ramps, 20 s at speed: ``--run-time``). libfranka's C++ example maps the circle to
``q_d`` with the robot's Cartesian motion generator running beside the torque loop; pylibfranka starts one or the
other, so here ``q_d`` follows the circle by resolved rates (``dq_d = J(q)^+ v_d``, orientation held, with the
robot's Jacobian). The JSON summary reports the worst ``|q_d - q|`` and the commanded-vs-measured torque RMS the
C++ example prints.
"""
import math
import time

import numpy as np
import pylibfranka
from common import K_MAX_TORQUE_RATE, arguments, connect, limit_rate, move_to, report, run, set_collision_20

K_GAINS = np.array([600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0])  # Nm/rad
D_GAINS = np.array([50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0])  # Nm s/rad


def main() -> None:
    args = arguments(__doc__, run_time=(float, 20.0, "time at speed on the circle, s (the example's: 20)"))
    radius, vel_max, acceleration_time, run_time = 0.05, 0.25, 2.0, args.run_time
    robot = connect(args.host)
    started = time.monotonic()
    move_to(robot)
    set_collision_20(robot)
    model = robot.load_model()
    t, vel, angle = 0.0, 0.0, 0.0
    q_d = None
    worst, tau_err_sq, n_err = 0.0, 0.0, 0
    control = robot.start_torque_control()

    def cb(state, period):
        nonlocal t, vel, angle, q_d, worst, tau_err_sq, n_err
        t += period
        q, dq = np.array(state.q), np.array(state.dq)
        if q_d is None:
            q_d = q.copy()
        # the circle's speed: ramp up, run, ramp down (the example's)
        if vel < vel_max and t < run_time:
            vel += period * abs(vel_max / acceleration_time)
        if vel > 0.0 and t > run_time:
            vel -= period * abs(vel_max / acceleration_time)
        vel = min(max(vel, 0.0), vel_max)
        angle += period * vel / abs(radius)
        # velocity along the circle delta_y = r (1 - cos), delta_z = r sin
        v = np.array([0.0, vel * math.sin(angle), vel * math.cos(angle), 0.0, 0.0, 0.0])
        J = np.array(model.zero_jacobian(state)).reshape(7, 6).T
        q_d = q_d + period * (np.linalg.pinv(J) @ v)
        worst = max(worst, float(np.abs(q_d - q).max()))
        coriolis = np.array(model.coriolis(state))
        tau = K_GAINS * (q_d - q) - D_GAINS * dq + coriolis
        tau = limit_rate(K_MAX_TORQUE_RATE, tau, np.array(state.tau_J_d))
        err = np.array(state.tau_J_d) + np.array(model.gravity(state)) - np.array(state.tau_J)
        tau_err_sq += float(err @ err) / 7
        n_err += 1
        return pylibfranka.Torques(tau.tolist()), t >= run_time + acceleration_time

    run(control, cb)
    report(args, robot, "joint_impedance_control", started, robot_time_s=t, worst_tracking_rad=worst,
           torque_error_rms_nm=math.sqrt(tau_err_sq / max(n_err, 1)))


if __name__ == "__main__":
    main()
