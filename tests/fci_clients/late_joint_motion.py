"""pylibfranka client for real-time mode: the joint position motion of libfranka's generate_joint_position_motion
(joints 4, 5, 7 by pi/8 (1 - cos(pi/2.5 t)), 5 s) that sleeps argv[2] seconds every 250 cycles, missing cycles as a
client on a loaded machine does; its clock follows the robot's (``period``), as libfranka's examples do."""
import json
import math
import sys
import time

import pylibfranka

robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
stall = float(sys.argv[2])
out = {"raised": None, "long_periods": 0, "cycles": 0}
control = robot.start_joint_position_control(pylibfranka.ControllerMode.JointImpedance)
t, q0 = 0.0, None
try:
    while True:
        state, period = control.readOnce()
        dt = period.to_sec()
        out["long_periods"] += dt > 0.0015
        t += dt
        if q0 is None:
            q0 = list(state.q_d)
        delta = math.pi / 8.0 * (1 - math.cos(math.pi / 2.5 * t))
        q = list(q0)
        for j in (3, 4, 6):
            q[j] += delta
        cmd = pylibfranka.JointPositions(q)
        cmd.motion_finished = t >= 5.0
        out["cycles"] += 1
        if out["cycles"] % 250 == 0:
            time.sleep(stall)
        control.writeOnce(cmd)
        if t >= 5.0:
            break
except pylibfranka.ControlException as e:
    out["raised"] = str(e)
print(json.dumps(out))
