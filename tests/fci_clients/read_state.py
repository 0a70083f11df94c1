"""pylibfranka client: read one state, load the model, print state fields and the model's B, g, C at that state."""
import json
import sys

import numpy as np
import pylibfranka

robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
state = robot.read_once()
model = robot.load_model()
later = robot.read_once()
fields = ("q", "dq", "tau_J", "O_T_EE", "F_T_EE", "F_T_NE", "NE_T_EE", "EE_T_K", "m_ee", "F_x_Cee", "I_ee", "m_total",
          "elbow", "O_ddP_O", "q_d", "theta")
out = {k: np.asarray(getattr(state, k), dtype=float).tolist() for k in fields}
out.update(robot_mode=str(state.robot_mode), time=state.time.to_sec(), later_time=later.time.to_sec(),
           success_rate=state.control_command_success_rate, errors=bool(state.current_errors),
           mass=list(model.mass(state)), gravity=list(model.gravity(state)), coriolis=list(model.coriolis(state)),
           server_version=robot.server_version() if hasattr(robot, "server_version") else None)
print(json.dumps(out))
