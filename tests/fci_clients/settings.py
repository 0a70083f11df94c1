"""pylibfranka client: end-effector and stiffness frames, a declared load, and what they change."""
import json
import sys

import numpy as np
import pylibfranka

robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
model = robot.load_model()
out = {}
NE_T_EE = np.eye(4)
NE_T_EE[2, 3] = 0.1  # 10 cm further along the tool axis
robot.set_EE(NE_T_EE.ravel(order="F").tolist())
EE_T_K = np.eye(4)
EE_T_K[0, 3] = 0.02
robot.set_K(EE_T_K.ravel(order="F").tolist())
robot.set_load(1.0, [0.0, 0.0, 0.05], [1e-3, 0, 0, 0, 1e-3, 0, 0, 0, 1e-3])
state = robot.read_once()
for k in ("q", "O_T_EE", "F_T_EE", "NE_T_EE", "EE_T_K", "F_x_Cload", "I_load", "F_x_Ctotal"):
    out[k] = list(getattr(state, k))
out.update(m_load=state.m_load, m_total=state.m_total, gravity=list(model.gravity(state)),
           mass=list(model.mass(state)))
# The robot now compensates the gravity of a 1 kg load the plant does not carry: with zero torques it drifts.
control = robot.start_torque_control()
for i in range(50):
    s, _ = control.readOnce()
    tau = pylibfranka.Torques([0.0] * 7)
    tau.motion_finished = i == 49
    control.writeOnce(tau)
out["q_after_50ms"] = list(robot.read_once().q)
print(json.dumps(out))
