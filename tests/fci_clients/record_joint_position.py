"""pylibfranka client: a 4 s joint motion (sinusoids on every joint) sent as joint positions to the robot's internal
joint impedance controller (start_joint_position_control), recorded with franka_vs_gym's StateRecorder, and, per
tick, libfranka's own model of the state (mass matrix, Coriolis and gravity torques from the URDF the robot sends)
for an independent inverse-dynamics check. Arguments: HOST OUT_DIR [SECONDS]; writes OUT_DIR/recorded.csv and
OUT_DIR/libfranka_model.npz (time, q, dq, tau_J, mass (N, 7, 7), coriolis, gravity (N, 7), float64)."""
import json
import math
import sys
from pathlib import Path

import numpy as np
import pylibfranka

from franka_vs_gym.validation.robot_states import StateRecorder

host, out = sys.argv[1], Path(sys.argv[2])
T = float(sys.argv[3]) if len(sys.argv) > 3 else 4.0
robot = pylibfranka.Robot(host, pylibfranka.RealtimeConfig.kIgnore)
model = robot.load_model()
rec = StateRecorder(seconds=T + 1)
rows = {k: [] for k in ("time", "q", "dq", "tau_J", "mass", "coriolis", "gravity")}
control = robot.start_joint_position_control(pylibfranka.ControllerMode.JointImpedance)
amp = np.array([0.2, 0.15, 0.2, 0.2, 0.25, 0.25, 0.3])
w = 2 * math.pi * np.array([0.31, 0.43, 0.37, 0.53, 0.61, 0.47, 0.71])  # rad/s
t, q0 = 0.0, None
while True:
    state, period = control.readOnce()
    rec(state)
    for k in ("q", "dq", "tau_J"):
        rows[k].append(list(state.__getattribute__(k)))
    rows["time"].append(state.time.to_sec())
    rows["mass"].append(model.mass(state))
    rows["coriolis"].append(model.coriolis(state))
    rows["gravity"].append(model.gravity(state))
    t += period.to_sec()
    if q0 is None:
        q0 = np.array(state.q_d)
    s = min(t, T)
    win = math.sin(math.pi * s / T) ** 2  # at rest at both ends
    cmd = pylibfranka.JointPositions((q0 + amp * win * np.sin(w * s)).tolist())
    cmd.motion_finished = t >= T
    control.writeOnce(cmd)
    if t >= T:
        break
rec.save(out / "recorded.csv")
arr = {k: np.array(v, dtype=float) for k, v in rows.items()}
arr["mass"] = arr["mass"].reshape(-1, 7, 7).transpose(0, 2, 1)  # column-major on the wire
np.savez(out / "libfranka_model.npz", **arr)
print(json.dumps({"n": rec.n, "dropped": rec.dropped}))
