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
import time

import numpy as np
from common import Q_READY, arguments, report
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


def main() -> None:
    args = arguments(__doc__, dynamics=(float, 0.05, "franky's relative_dynamics_factor (README: 0.05)"))
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
    errors["cartesian_motion_m"] = float(np.linalg.norm(moved - np.array([0.05, 0.0, 0.0])))
    robot.move(CartesianWaypointMotion([CartesianWaypoint(RobotPose(pose0))]))
    errors["cartesian_waypoint_motion_m"] = float(np.linalg.norm(robot.current_pose.end_effector_pose.translation
                                                                 - pose0.translation))
    z0 = robot.current_pose.end_effector_pose.translation[2]
    robot.move(CartesianVelocityMotion(RobotVelocity(Twist([0.0, 0.0, 0.02])), duration=Duration(1000)))
    errors["cartesian_velocity_motion_moved_m"] = float(robot.current_pose.end_effector_pose.translation[2] - z0)
    state = robot.state
    report(args, _Reader(state), "franky_examples", started, errors_by_motion=errors,
           worst_error=max(v for k, v in errors.items() if "moved" not in k))


class _Reader:
    """The last franky state in the shape :func:`common.report` reads (``read_once``)."""

    def __init__(self, state):
        self.state = state

    def read_once(self):
        return self.state


if __name__ == "__main__":
    main()
