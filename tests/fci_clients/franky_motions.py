"""franky client: a joint motion, a relative Cartesian motion and a Cartesian motion back, reporting where the
robot ended."""
import json
import sys

import numpy as np
from franky import Affine, CartesianMotion, JointMotion, RealtimeConfig, ReferenceType, Robot

robot = Robot(sys.argv[1], realtime_config=RealtimeConfig.Ignore)
robot.relative_dynamics_factor = 0.2
out = {}
q_target = [0.2, -0.6, -0.1, -2.2, 0.1, 1.7, 0.6]
robot.move(JointMotion(q_target))
out["q_after_joint"] = robot.current_joint_positions.tolist()
p0 = robot.current_pose.end_effector_pose.translation.tolist()
quat0 = robot.current_pose.end_effector_pose.quaternion.tolist()
robot.move(CartesianMotion(Affine([0.05, -0.03, -0.04]), ReferenceType.Relative))
p1 = robot.current_pose.end_effector_pose.translation.tolist()
q1 = robot.current_pose.end_effector_pose.quaternion.tolist()
robot.move(CartesianMotion(Affine(p0, quat0), ReferenceType.Absolute))
p2 = robot.current_pose.end_effector_pose.translation.tolist()
out.update(q_target=q_target, p0=p0, p1=p1, p2=p2, quat1=q1, quat0=quat0,
           quat2=robot.current_pose.end_effector_pose.quaternion.tolist(),
           state_q=np.asarray(robot.state.q).tolist())
print(json.dumps(out))
