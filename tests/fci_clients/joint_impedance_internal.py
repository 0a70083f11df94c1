"""pylibfranka client: joint position motion (cosine profile on joints 3 and 4) through the robot's internal joint
impedance controller, then report where the robot ended and how closely it tracked."""
import json
import math
import sys

import numpy as np
import pylibfranka

robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
robot.set_joint_impedance([3000, 3000, 3000, 2500, 2500, 2000, 2000])
control = robot.start_joint_position_control(pylibfranka.ControllerMode.JointImpedance)
T = 2.0
t = 0.0
q0 = None
err = 0.0
while True:
    state, duration = control.readOnce()
    t += duration.to_sec()
    if q0 is None:
        q0 = np.array(state.q)
    err = max(err, float(np.abs(np.array(state.q_d) - np.array(state.q)).max()))
    delta = 0.3 * (1 - math.cos(math.pi * min(t, T) / T)) / 2
    q = q0.copy()
    q[2] += delta
    q[3] += delta
    cmd = pylibfranka.JointPositions(q.tolist())
    cmd.motion_finished = t >= T
    control.writeOnce(cmd)
    if t >= T:
        break
state = robot.read_once()
print(json.dumps({"q0": q0.tolist(), "q": list(state.q), "max_tracking_error": err, "mode": str(state.robot_mode)}))
