"""pylibfranka client: gravity-free torque control with zero torques for N ms (the robot adds gravity), then stop."""
import json
import sys

import pylibfranka

n = int(sys.argv[2]) if len(sys.argv) > 2 else 1000
robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
model = robot.load_model()
control = robot.start_torque_control()
qs, taus, grav, times = [], [], [], []
for i in range(n):
    state, duration = control.readOnce()
    qs.append(list(state.q))
    taus.append(list(state.tau_J))
    grav.append(list(model.gravity(state)))
    times.append(state.time.to_sec())
    tau = pylibfranka.Torques([0.0] * 7)
    tau.motion_finished = i == n - 1
    control.writeOnce(tau)
print(json.dumps({"q": qs, "tau_J": taus, "gravity": grav, "time": times}))
