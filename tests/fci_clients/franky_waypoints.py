"""franky client: play a designed excitation (``franka-vs excite``'s trajectory.csv, argv[2]) as a JointWaypointMotion
through its positions and velocities every 50 ms, each waypoint reached in that time, and record the robot state to
argv[3] (+ .json sidecar). franky's JointState carries no acceleration, so every waypoint is reached at zero
acceleration: a torque ripple at 20 Hz and its harmonics (how franka-vs excite's franky script played a design until
2026-11-27, and how a user's waypoint script plays one). Prints the recorder's summary as JSON."""
import json
import sys

import numpy as np
from franky import (
                    Duration,
                    JointMotion,
                    JointState,
                    JointWaypoint,
                    JointWaypointMotion,
                    RealtimeConfig,
                    RelativeDynamicsFactor,
                    Robot,
)

from franka_vs_gym.validation.readers.robot_states import StateRecorder

STEP = 0.05  # s between waypoints
design = np.loadtxt(sys.argv[2], delimiter=",", skiprows=1)  # time, q_d[7], dq_d[7], ddq_d[7]
t, q, dq = design[:, 0], design[:, 1:8], design[:, 8:15]
robot = Robot(sys.argv[1], realtime_config=RealtimeConfig.Ignore)
robot.relative_dynamics_factor = RelativeDynamicsFactor(0.2, 0.2, 0.2)
robot.move(JointMotion(q[0].tolist()))
robot.relative_dynamics_factor = 1.0
rows = np.searchsorted(t, np.arange(STEP, t[-1] + 1e-9, STEP))
waypoints = [JointWaypoint(JointState(q[k].tolist(), dq[k].tolist()), minimum_time=Duration(int(STEP * 1000)))
             for k in rows]
motion = JointWaypointMotion(waypoints)
rec = StateRecorder(seconds=float(t[-1]) + 5)
motion.register_callback(rec)
robot.move(motion)
rec.save(sys.argv[3])
print(json.dumps({"log": sys.argv[3], "samples": rec.n, "dropped": rec.dropped}))
