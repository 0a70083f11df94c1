#!/usr/bin/env python
"""libfranka's generate_elbow_motion for franky: the elbow swings out by pi/5 and back while the hand holds its pose.

    python examples/libfranka/generate_elbow_motion.py 127.0.0.1      # franka-vs serve, or 172.16.0.2

The C++ example sets the default behaviour, moves to the ready pose (speed factor 0.5), sets the collision
thresholds (20/18/16/14/12 Nm, 20/25 N, Nm) and then commands, for 10 s, the start pose ``O_T_EE_c`` with the elbow
(joint 3) at ``elbow_c[0] + pi/10 (1 - cos(pi/5 t))``: out by pi/5 at 5 s and back at 10 s, the joint-4 flip kept.
pylibfranka 0.21.3 cannot send an elbow (its ``CartesianPose`` takes ``O_T_EE`` only), so this port uses franky,
whose Cartesian motions carry one (``RobotPose(pose, ElbowState(joint_3_pos, joint_4_flip))``) and run in
libfranka's ``Robot::control`` (100 Hz low-pass on the pose and the elbow, as the C++ example gets): the same two
legs, the pose held at the start's ``O_T_EE_c``, each leg planned by franky (Ruckig) to take at least 5 s
(``--leg-time``) within ``--dynamics`` times the robot's limits. The JSON summary gives the elbow reached at the
turn, how far the hand moved from its start pose during the motion (the example's own measure: the pose is held),
and the elbow and pose at the end.
"""
import argparse
import json
import math
import time

import numpy as np
from franky import (
    CartesianWaypoint,
    CartesianWaypointMotion,
    Duration,
    ElbowState,
    JointMotion,
    RealtimeConfig,
    Robot,
    RobotPose,
)

Q_READY = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)  # (franky and pylibfranka
# cannot share a process, so this script does not import common.py)
SWING = math.pi / 5  # rad: the C++ example's peak, pi/10 (1 - cos(pi))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("host", help="robot (or simulator) address")
    ap.add_argument("--json", action="store_true", help="print a JSON summary")
    ap.add_argument("--leg-time", type=float, default=5.0, help="s: the shortest time of each leg (C++: 5 s)")
    ap.add_argument("--dynamics", type=float, default=0.1,
                    help="franky's relative_dynamics_factor for the elbow legs (velocity, acceleration and jerk "
                         "limits of the elbow and the pose scaled by it)")
    args = ap.parse_args()
    robot = Robot(args.host, realtime_config=RealtimeConfig.Ignore)
    # setDefaultBehavior: collision thresholds, joint and Cartesian impedance (examples_common.cpp)
    robot.set_collision_behavior([10.0] * 7, [20.0] * 7, [10.0] * 6, [20.0] * 6)
    robot.set_joint_impedance([3000, 3000, 3000, 2500, 2500, 2000, 2000])
    robot.set_cartesian_impedance([3000, 3000, 3000, 300, 300, 300])
    started = time.monotonic()
    robot.relative_dynamics_factor = 0.5  # MotionGenerator(0.5, q_goal) of the C++ example, in franky's terms
    robot.move(JointMotion(Q_READY))
    torques = [20.0, 20.0, 18.0, 18.0, 16.0, 14.0, 12.0]
    forces = [20.0, 20.0, 20.0, 25.0, 25.0, 25.0]
    robot.set_collision_behavior(torques, torques, forces, forces)
    robot.relative_dynamics_factor = args.dynamics

    state = robot.state
    pose0 = state.O_T_EE_c  # the C++ example's initial_pose and initial_elbow
    elbow0 = state.elbow_c
    p0 = np.array(pose0.translation)
    drift = [0.0]
    elbow_peak = [elbow0.joint_3_pos]
    robot_time = [0.0]

    def watch(s, time_step, rel_time, *_):  # the hand's distance from its start pose and the elbow, every cycle
        robot_time[0] = rel_time.to_sec()
        d = s.O_T_EE.translation - p0
        drift[0] = max(drift[0], float(math.sqrt(d @ d)))
        e = s.elbow.joint_3_pos
        if abs(e - elbow0.joint_3_pos) > abs(elbow_peak[0] - elbow0.joint_3_pos):
            elbow_peak[0] = e

    leg = Duration(int(round(args.leg_time * 1000)))
    out_elbow = ElbowState(elbow0.joint_3_pos + SWING, elbow0.joint_4_flip)
    motion = CartesianWaypointMotion([CartesianWaypoint(RobotPose(pose0, out_elbow), minimum_time=leg),
                                      CartesianWaypoint(RobotPose(pose0, elbow0), minimum_time=leg)])
    motion.register_callback(watch)
    t0 = time.monotonic()
    robot.move(motion)
    motion_wall = time.monotonic() - t0

    end = robot.state
    out = {"example": "generate_elbow_motion", "q": list(end.q), "errors": str(end.current_errors),
           "robot_mode": str(end.robot_mode), "wall_s": time.monotonic() - started, "motion_wall_s": motion_wall,
           "robot_time_s": robot_time[0],
           "elbow_start_rad": elbow0.joint_3_pos, "elbow_peak_rad": elbow_peak[0],
           "elbow_swing_error_rad": abs(elbow_peak[0] - elbow0.joint_3_pos - SWING),
           "elbow_return_error_rad": abs(end.elbow.joint_3_pos - elbow0.joint_3_pos),
           "worst_drift_m": drift[0],
           "return_error_m": float(np.linalg.norm(np.array(end.O_T_EE.translation) - p0))}
    print(json.dumps(out) if args.json else "\n".join(f"{k}: {v}" for k, v in out.items()))


if __name__ == "__main__":
    main()
