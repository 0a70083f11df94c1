"""pylibfranka client for real-time mode: torque control that stalls for argv[2] seconds after 200 cycles."""
import json
import sys
import time

import pylibfranka

robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
stall = float(sys.argv[2])
out = {"raised": None, "rates": []}
control = robot.start_torque_control()
try:
    for i in range(600):
        state, _ = control.readOnce()
        out["rates"].append(state.control_command_success_rate)
        if i == 200:
            time.sleep(stall)
        tau = pylibfranka.Torques([0.0] * 7)
        tau.motion_finished = i == 599
        control.writeOnce(tau)
except pylibfranka.ControlException as e:
    out["raised"] = str(e)
print(json.dumps(out))
