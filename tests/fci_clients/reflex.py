"""pylibfranka client: provoke a reflex, print the ControlException and the state, recover, move again.

argv: host, kind ("torque_jump": a 5 Nm step in the torque command -> controller_torque_discontinuity;
"position_limit": drive joint 7 at 1 rad/s into its upper limit -> joint_position_limits_violation;
"velocity": a joint velocity command above the limit -> joint_motion_generator_velocity_limits_violation;
"acceleration": a 0.1 rad/s step in a joint velocity command -> joint_motion_generator_velocity_discontinuity;
"cartesian_speed": the end effector turned about its own axis (joint 7 alone) at up to 2.55 rad/s, above the
2.5 rad/s Cartesian limit but below joint 7's 2.61 rad/s -> cartesian_motion_generator_velocity_limits_violation)."""
import json
import sys

import numpy as np
import pylibfranka

host, kind = sys.argv[1], sys.argv[2]
robot = pylibfranka.Robot(host, pylibfranka.RealtimeConfig.kIgnore)
out = {}
control = None
try:
    if kind == "velocity":
        control = robot.start_joint_velocity_control(pylibfranka.ControllerMode.JointImpedance)
        for i in range(800):
            state, _ = control.readOnce()
            s = min(1.0, i / 600)
            dq = [0.0] * 7
            dq[0] = 3.0 * s * s * (3 - 2 * s)  # smooth ramp to 3 rad/s, above joint 1's 2.175 rad/s
            control.writeOnce(pylibfranka.JointVelocities(dq))
    elif kind == "acceleration":
        control = robot.start_joint_velocity_control(pylibfranka.ControllerMode.JointImpedance)
        for i in range(100):
            state, _ = control.readOnce()
            dq = [0.0] * 7
            dq[0] = 0.1 if i >= 10 else 0.0
            control.writeOnce(pylibfranka.JointVelocities(dq))
    elif kind == "cartesian_speed":
        control = robot.start_cartesian_velocity_control(pylibfranka.ControllerMode.JointImpedance)
        for i in range(800):
            state, _ = control.readOnce()
            s = min(1.0, i / 500)
            v = [0.0] * 6
            v[5] = -2.55 * s * s * (3 - 2 * s)  # about the base's -z = the end effector's z in the start pose
            control.writeOnce(pylibfranka.CartesianVelocities(v))
    else:
        control = robot.start_torque_control()
        for i in range(5000):
            state, _ = control.readOnce()
            tau = np.zeros(7)
            if kind == "torque_jump":
                tau[0] = 5.0 if i >= 10 else 0.0
            else:
                tau[6] = float(np.clip(0.5 * (1.0 - state.dq[6]), -0.5, 0.5))
            control.writeOnce(pylibfranka.Torques(tau.tolist()))
    out["raised"] = None
except pylibfranka.ControlException as e:
    out["raised"] = str(e)
control = None  # drop the active control: it holds the control lock
state = robot.read_once()
out["mode_after"] = str(state.robot_mode)
out["last_motion_errors"] = str(state.last_motion_errors)
out["current_errors"] = str(state.current_errors)
out["q_at_reflex"] = list(state.q)
robot.automatic_error_recovery()
for _ in range(3):
    state = robot.read_once()
out["mode_recovered"] = str(state.robot_mode)
out["errors_recovered"] = bool(state.current_errors)
# move again: for the position limit, back out of it
control = robot.start_torque_control()
for i in range(300):
    state, _ = control.readOnce()
    tau = np.zeros(7)
    if kind == "position_limit":
        tau[6] = float(np.clip(0.5 * (-0.5 - state.dq[6]), -0.5, 0.5))
    cmd = pylibfranka.Torques(tau.tolist())
    cmd.motion_finished = i == 299
    control.writeOnce(cmd)
out["q_end"] = list(robot.read_once().q)
print(json.dumps(out))
