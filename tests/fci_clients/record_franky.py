"""franky client: a 4 s joint motion (sinusoids on every joint) tracked by franky's own torque-level joint impedance
controller (JointImpedanceTrackingMotion, the reference updated from the motion callback), recorded with
franka_vs_gym's StateRecorder in that callback, and dumped the ways users save franky states: a JSON list of
per-tick dicts with the time in ms (Duration.to_msec()) under "robot_time", an NPZ of stacked arrays with the time in
ms, and a pickle of the RobotState objects. Arguments: HOST OUT_DIR [SECONDS]."""
import json
import math
import pickle
import sys
import time
from pathlib import Path

import numpy as np
from franky import JointImpedanceTrackingMotion, JointReference, RealtimeConfig, Robot

from franka_vs_gym.validation.robot_states import StateRecorder

host, out = sys.argv[1], Path(sys.argv[2])
T = float(sys.argv[3]) if len(sys.argv) > 3 else 4.0
robot = Robot(host, realtime_config=RealtimeConfig.Ignore)
rec = StateRecorder(seconds=T + 2)
states = []
q0 = np.asarray(robot.state.q, dtype=float)
amp = np.array([0.2, 0.15, 0.2, 0.2, 0.25, 0.25, 0.3])
w = 2 * math.pi * np.array([0.31, 0.43, 0.37, 0.53, 0.61, 0.47, 0.71])  # rad/s
motion = JointImpedanceTrackingMotion(stiffness=[600, 600, 600, 600, 250, 150, 50],
                                      damping=[50, 50, 50, 50, 20, 15, 5])
t_start = []


N = int(T * 1000) + 200  # ticks kept: the motion, then 0.2 s at rest (the loop runs on until stop() preempts it)


def step(state, time_step, rel_time, abs_time, signal):
    if rec.n < N:
        rec(state)
        states.append(state)
    s = min(rel_time.to_sec(), T)
    win, dwin = math.sin(math.pi * s / T) ** 2, math.pi / T * math.sin(2 * math.pi * s / T)
    q = q0 + amp * win * np.sin(w * s)
    dq = amp * (dwin * np.sin(w * s) + win * w * np.cos(w * s))
    motion.set_reference(JointReference(q, dq))


motion.register_callback(step)
robot.move(motion, asynchronous=True)
while rec.n < N:
    time.sleep(0.01)
robot.stop()
try:
    robot.join_motion()
except Exception:  # stopping a motion that never finishes by itself ends it with an exception
    pass
rec.save(out / "recorded.npz")
ticks = [{"robot_time": s.time.to_msec(), "q": s.q.tolist(), "dq": s.dq.tolist(), "tau_J": s.tau_J.tolist(),
          "tau_J_d": s.tau_J_d.tolist()} for s in states]
(out / "states.json").write_text(json.dumps(ticks))
np.savez(out / "stacked.npz", time=np.array([s.time.to_msec() for s in states], dtype=float),
         q=np.array([s.q for s in states]), dq=np.array([s.dq for s in states]),
         tau_J=np.array([s.tau_J for s in states]))
with open(out / "states.pkl", "wb") as fh:
    pickle.dump(states, fh)
print(json.dumps({"n": rec.n, "dropped": rec.dropped, "ticks": len(states)}))
