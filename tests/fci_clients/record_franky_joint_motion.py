"""franky client: a joint motion through two waypoints and back (JointWaypointMotion; franky's JointMotion is its
one-waypoint case: joint positions from franky's trajectory generator, tracked by the robot's internal joint
impedance controller), recorded with franka_vs_gym's StateRecorder as the motion callback. Arguments: HOST OUT_DIR;
writes OUT_DIR/recorded.npz."""
import json
import sys
from pathlib import Path

import numpy as np
from franky import JointWaypoint, JointWaypointMotion, RealtimeConfig, RelativeDynamicsFactor, Robot

from franka_vs_gym.validation.robot_states import StateRecorder

host, out = sys.argv[1], Path(sys.argv[2])
robot = Robot(host, realtime_config=RealtimeConfig.Ignore)
# a gentle jerk limit (0.4 % of the FER's): the accelerations ramp over about 0.1 s, so the workbench's 10 Hz filter
# of q and dq keeps the motion's inertial torque (with the jerk at 25 %, as the acceleration, it steps within a few
# ms and the log's noise floor, torque content above the filter, is 0.2-0.37 Nm on joints 0-3)
robot.relative_dynamics_factor = RelativeDynamicsFactor(0.3, 0.25, 0.004)
q0 = np.asarray(robot.state.q, dtype=float)
step = np.array([0.4, 0.3, -0.4, 0.4, 0.5, -0.4, 0.6])
motion = JointWaypointMotion([JointWaypoint((q0 + step).tolist()), JointWaypoint((q0 - 0.5 * step).tolist()),
                              JointWaypoint(q0.tolist())])
rec = StateRecorder(seconds=30)
motion.register_callback(rec)
robot.move(motion)
rec.save(out / "recorded.npz")
print(json.dumps({"n": rec.n, "dropped": rec.dropped}))
