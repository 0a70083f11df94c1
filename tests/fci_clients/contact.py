"""pylibfranka client: push the hand 3 cm down onto a block with the internal Cartesian impedance, hold, report the
estimated external wrench; argv[2] = upper force threshold (N) of the collision behaviour."""
import json
import math
import sys

import numpy as np
import pylibfranka

robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
f_max = float(sys.argv[2])
robot.set_collision_behavior([100.0] * 7, [100.0] * 7, [f_max / 2] * 6, [f_max] * 6)
robot.set_cartesian_impedance([3000, 3000, 3000, 300, 300, 300])
control = robot.start_cartesian_pose_control(pylibfranka.ControllerMode.CartesianImpedance)
out = {"raised": None}
t, T, start = 0.0, 1.0, None
try:
    while True:
        state, period = control.readOnce()
        t += period.to_sec()
        if start is None:
            start = np.array(state.O_T_EE).reshape(4, 4, order="F")
        M = start.copy()
        M[2, 3] -= 0.03 * (1 - math.cos(math.pi * min(t, T) / T)) / 2
        cmd = pylibfranka.CartesianPose(M.ravel(order="F").tolist())
        cmd.motion_finished = t >= T + 0.5
        out.update(z_d=M[2, 3], z=state.O_T_EE[14], F=list(state.O_F_ext_hat_K),
                   tau_ext=list(state.tau_ext_hat_filtered), contact=list(state.cartesian_contact),
                   collision=list(state.cartesian_collision))
        control.writeOnce(cmd)
        if t >= T + 0.5:
            break
except pylibfranka.ControlException as e:
    out["raised"] = str(e)
print(json.dumps(out))
