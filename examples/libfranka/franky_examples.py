#!/usr/bin/env python
"""franky's documented motions, one after the other: the franky side of the libfranka examples.

    python examples/libfranka/franky_examples.py 127.0.0.1      # franka-vs serve, or 172.16.0.2

The motions of franky's README at its suggested ``relative_dynamics_factor`` of 0.05 (``--dynamics`` to change
it): a joint motion to the ready pose, a joint waypoint motion (two waypoints, back to ready), a joint velocity
motion (joint 7 at 0.1 rad/s for 1 s, then stopped), a relative Cartesian motion (5 cm along x) and back with a
Cartesian waypoint motion, and a Cartesian velocity motion (2 cm/s along z for 1 s). franky plans every motion
within the robot's limits (Ruckig); each ends when the target is reached. The JSON summary gives each motion's
final error.
"""
import argparse
import json
import math
import time

import numpy as np
from franky import (
    Affine,
    CartesianMotion,
    CartesianVelocityMotion,
    CartesianWaypoint,
    CartesianWaypointMotion,
    Duration,
    JointMotion,
    JointState,
    JointVelocityMotion,
    JointWaypoint,
    JointWaypointMotion,
    RealtimeConfig,
    ReferenceType,
    Robot,
    RobotPose,
    RobotVelocity,
    Twist,
)

Q_READY = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)  # (franky and pylibfranka
# cannot share a process, so this script does not import common.py)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("host", help="robot (or simulator) address")
    ap.add_argument("--json", action="store_true", help="print a JSON summary")
    ap.add_argument("--dynamics", type=float, default=0.05, help="franky's relative_dynamics_factor (README: 0.05)")
    args = ap.parse_args()
    robot = Robot(args.host, realtime_config=RealtimeConfig.Ignore)
    robot.relative_dynamics_factor = args.dynamics
    started = time.monotonic()
    errors = {}
    q_ready = np.array(Q_READY)

    def joint_error(target):
        return float(np.abs(robot.current_joint_positions - np.asarray(target)).max())

    robot.move(JointMotion(q_ready))
    errors["joint_motion_rad"] = joint_error(q_ready)
    q_a = q_ready + np.array([0.2, 0.1, -0.1, 0.1, 0.0, 0.1, -0.2])
    robot.move(JointWaypointMotion([JointWaypoint(JointState(q_a)), JointWaypoint(JointState(q_ready))]))
    errors["joint_waypoint_motion_rad"] = joint_error(q_ready)
    q_before = robot.current_joint_positions
    robot.move(JointVelocityMotion([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1], duration=Duration(1000)))
    errors["joint_velocity_motion_moved_rad"] = float(robot.current_joint_positions[6] - q_before[6])
    pose0 = robot.current_pose.end_effector_pose
    robot.move(CartesianMotion(Affine([0.05, 0.0, 0.0]), ReferenceType.Relative))
    moved = robot.current_pose.end_effector_pose.translation - pose0.translation
    # (a relative target is composed in the end-effector frame: the hand moved 5 cm along its own x axis)
    x_ee = np.asarray(pose0.matrix)[:3, 0]
    errors["cartesian_motion_m"] = float(np.linalg.norm(moved - 0.05 * x_ee))
    robot.move(CartesianWaypointMotion([CartesianWaypoint(RobotPose(pose0))]))
    errors["cartesian_waypoint_motion_m"] = float(np.linalg.norm(robot.current_pose.end_effector_pose.translation
                                                                 - pose0.translation))
    z0 = robot.current_pose.end_effector_pose.translation[2]
    robot.move(CartesianVelocityMotion(RobotVelocity(Twist([0.0, 0.0, 0.02])), duration=Duration(1000)))
    errors["cartesian_velocity_motion_moved_m"] = float(robot.current_pose.end_effector_pose.translation[2] - z0)
    state = robot.state
    out = {"example": "franky_examples", "q": list(state.q), "errors": str(state.current_errors),
           "robot_mode": str(state.robot_mode), "wall_s": time.monotonic() - started, "errors_by_motion": errors,
           "worst_error": max(v for k, v in errors.items() if "moved" not in k)}
    print(json.dumps(out) if args.json else "\n".join(f"{k}: {v}" for k, v in out.items()))


if __name__ == "__main__":
    main()
