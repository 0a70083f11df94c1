"""pylibfranka client: a 4 s joint motion (sinusoids on every joint) under a joint PD torque controller with Coriolis
feed-forward (libfranka's joint-impedance example law; the robot adds gravity), recorded with
franka_vs_gym's StateRecorder inside the control loop, and dumped the ways users save robot states: JSON lines of
per-tick dicts (time in s from Duration.to_sec()), CSV with q_0.. columns and CSV with whole lists in one cell, a
structured .npy. Arguments: HOST OUT_DIR [SECONDS]."""
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import pylibfranka

from franka_vs_gym.validation.robot_states import StateRecorder

host, out = sys.argv[1], Path(sys.argv[2])
T = float(sys.argv[3]) if len(sys.argv) > 3 else 4.0
FIELDS = ("q", "dq", "tau_J", "tau_J_d", "q_d", "dq_d")
robot = pylibfranka.Robot(host, pylibfranka.RealtimeConfig.kIgnore)
rec = StateRecorder(seconds=T + 1)
ticks = []
model = robot.load_model()
control = robot.start_torque_control()
kp = np.array([600.0, 600, 600, 600, 250, 150, 50])
kd = np.array([50.0, 50, 50, 50, 20, 15, 5])
amp = np.array([0.2, 0.15, 0.2, 0.2, 0.25, 0.25, 0.3])
freq = np.array([0.31, 0.43, 0.37, 0.53, 0.61, 0.47, 0.71])  # Hz
t, q0 = 0.0, None
while True:
    state, period = control.readOnce()
    rec(state)
    ticks.append({"time": state.time.to_sec(), **{f: list(getattr(state, f)) for f in FIELDS},
                  "robot_mode": str(state.robot_mode), "m_total": state.m_total,
                  "F_x_Ctotal": list(state.F_x_Ctotal), "I_total": list(state.I_total)})
    t += period.to_sec()
    if q0 is None:
        q0 = np.array(state.q)
    s = min(t, T)
    w = 2 * math.pi * freq
    win, dwin = math.sin(math.pi * s / T) ** 2, math.pi / T * math.sin(2 * math.pi * s / T)  # at rest at both ends
    q_d = q0 + amp * win * np.sin(w * s)
    dq_d = amp * (dwin * np.sin(w * s) + win * w * np.cos(w * s))
    tau = kp * (q_d - np.array(state.q)) + kd * (dq_d - np.array(state.dq)) + np.array(model.coriolis(state))
    cmd = pylibfranka.Torques(tau.tolist())
    cmd.motion_finished = t >= T
    control.writeOnce(cmd)
    if t >= T:
        break
rec.save(out / "recorded.csv")
with open(out / "states.jsonl", "w") as fh:
    for tick in ticks:
        fh.write(json.dumps(tick) + "\n")
with open(out / "flat.csv", "w", newline="") as fh:
    w = csv.writer(fh)
    w.writerow(["time"] + [f"{f}_{i}" for f in FIELDS for i in range(7)] + ["robot_mode"])
    for tick in ticks:
        w.writerow([tick["time"]] + [v for f in FIELDS for v in tick[f]] + [tick["robot_mode"]])
with open(out / "cells.csv", "w", newline="") as fh:  # a list per cell, as str() and numpy print it
    w = csv.writer(fh)
    w.writerow(["", "time", "q", "dq", "tau_J"])
    for k, tick in enumerate(ticks):
        w.writerow([k, tick["time"], str(tick["q"]), np.array2string(np.array(tick["dq"]), precision=17),
                    str(tick["tau_J"])])
dt = np.dtype([("time", "f8")] + [(f, "f8", (7,)) for f in FIELDS])
arr = np.zeros(len(ticks), dtype=dt)
for k, tick in enumerate(ticks):
    arr[k] = (tick["time"], *[tick[f] for f in FIELDS])
np.save(out / "states.npy", arr)
print(json.dumps({"n": rec.n, "dropped": rec.dropped, "ticks": len(ticks)}))
