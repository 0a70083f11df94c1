"""pylibfranka client: Cartesian pose (internal Cartesian impedance), Cartesian velocity and joint velocity motions
with cosine profiles; reports start and end poses and joint positions."""
import json
import math
import sys

import numpy as np
import pylibfranka

robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
robot.set_cartesian_impedance([3000, 3000, 3000, 300, 300, 300])
out = {}


def run(control, command, T):
    t, first = 0.0, None
    while True:
        state, period = control.readOnce()
        t += period.to_sec()
        if first is None:
            first = state
        cmd = command(first, min(t, T), T)
        cmd.motion_finished = t >= T
        control.writeOnce(cmd)
        if t >= T:
            return first


# 1. Cartesian pose, Cartesian impedance: 3 cm down in z in 1.5 s
def pose(first, t, T):
    M = np.array(first.O_T_EE).reshape(4, 4, order="F")
    M[2, 3] -= 0.03 * (1 - math.cos(math.pi * t / T)) / 2
    return pylibfranka.CartesianPose(M.ravel(order="F").tolist())


first = run(robot.start_cartesian_pose_control(pylibfranka.ControllerMode.CartesianImpedance), pose, 1.5)
for _ in range(300):  # let the impedance settle
    robot.read_once()
end = robot.read_once()
out["cart_pose"] = {"start": list(first.O_T_EE), "end": list(end.O_T_EE)}


# 2. Cartesian velocity, joint impedance: +x at up to 0.1 m/s for 1 s (displacement 5 cm)
def velocity(first, t, T):
    v = 0.1 * math.sin(math.pi * t / T)
    return pylibfranka.CartesianVelocities([v, 0.0, 0.0, 0.0, 0.0, 0.0])


first = run(robot.start_cartesian_velocity_control(pylibfranka.ControllerMode.JointImpedance), velocity, 1.0)
end = robot.read_once()
out["cart_velocity"] = {"start": list(first.O_T_EE), "end": list(end.O_T_EE)}


# 3. joint velocity, joint impedance: joint 4 (index 3) at up to 0.4 rad/s for 1 s (0.2546 rad)
def joint_velocity(first, t, T):
    dq = [0.0] * 7
    dq[3] = 0.4 * math.sin(math.pi * t / T)
    return pylibfranka.JointVelocities(dq)


first = run(robot.start_joint_velocity_control(pylibfranka.ControllerMode.JointImpedance), joint_velocity, 1.0)
end = robot.read_once()
out["joint_velocity"] = {"start": list(first.q), "end": list(end.q)}
print(json.dumps(out))
