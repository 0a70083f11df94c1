"""franky client for real-time mode: an elbow motion (the hand held, the elbow out by argv[3] rad, relative dynamics
factor 0.05) whose control loop stalls argv[2] seconds every 250 cycles (a Python callback that sleeps), so some of
its commands come after their cycle, as a client on a loaded machine sends them. libfranka's Robot::control
low-passes each command against the state's O_T_EE_c and elbow_c (100 Hz). Prints the exception (if any) and what
the client saw."""
import json
import sys
import time

from franky import CartesianMotion, ElbowState, RealtimeConfig, Robot, RobotPose

robot = Robot(sys.argv[1], realtime_config=RealtimeConfig.Ignore)
stall, swing = float(sys.argv[2]), float(sys.argv[3])
robot.relative_dynamics_factor = 0.05
state = robot.state
e0 = state.elbow_c
out = {"raised": None, "cycles": 0, "long_periods": 0, "elbow_start": e0.joint_3_pos}


def cb(s, step, *_):
    out["cycles"] += 1
    out["long_periods"] += step.to_msec() > 1
    if out["cycles"] % 250 == 100:
        time.sleep(stall)


m = CartesianMotion(RobotPose(state.O_T_EE_c, ElbowState(e0.joint_3_pos + swing, e0.joint_4_flip)))
m.register_callback(cb)
try:
    robot.move(m)
except Exception as e:  # noqa: BLE001 (reported to the test)
    out["raised"] = str(e)
out["elbow_end"] = robot.state.elbow.joint_3_pos
print(json.dumps(out))
