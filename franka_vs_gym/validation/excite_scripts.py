"""What ``franka-vs excite`` writes: the designed trajectory as a table and CSV, and the pylibfranka and franky
scripts that play it on a robot (or on ``franka-vs serve``) and record the robot state."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np

from franka_vs_gym.validation.excite_motion import FourierMotion

if TYPE_CHECKING:
    from franka_vs_gym.validation.excite import Design


# ---------------------------------------------------------------------------------------------- outputs
def trajectory_table(motion: FourierMotion, rate: float = 1000.0) -> np.ndarray:
    """(n, 22) rows time, q_d[0..6], dq_d[0..6], ddq_d[0..6] at ``rate``."""
    t = np.arange(int(round(motion.duration * rate)) + 1) / rate
    q, dq, ddq, _ = motion.sample(t)
    return np.column_stack([t, q, dq, ddq])


def trajectory_csv(motion: FourierMotion, rate: float = 1000.0, table: np.ndarray | None = None) -> str:
    """trajectory.csv's text: the rows of :func:`trajectory_table` (or the given ``table`` of them)."""
    head = ",".join(["time"] + [f"{n}[{j}]" for n in ("q_d", "dq_d", "ddq_d") for j in range(7)])
    rows = (trajectory_table(motion, rate) if table is None else table) + 0.0  # (no negative zeros)
    body = "\n".join(",".join(f"{v:.9g}" for v in r) for r in rows)
    return head + "\n" + body + "\n"


_MOTION_CODE = '''
MOTION = json.loads({motion!r})
CENTRE = np.array(MOTION["centre_rad"])
A, B = np.array(MOTION["a_rad"]), np.array(MOTION["b_rad"])
PERIOD, PERIODS, REST = MOTION["period_s"], MOTION["periods"], MOTION["rest_s"]
DURATION = MOTION["duration_s"]
W = 2 * math.pi * np.arange(1, A.shape[1] + 1) / PERIOD
DQ_MAX = np.array({dq_max!r})  # rad/s, the robot's limits
DDQ_MAX = np.array({ddq_max!r})  # rad/s^2


def excitation(t, acceleration=False):
    """Designed joint positions and velocities (and with ``acceleration`` accelerations) at time t (s)."""
    s = min(max(t - REST, 0.0), PERIOD * PERIODS)
    sn, cs = np.sin(W * s), np.cos(W * s)
    moving = REST < t < REST + PERIOD * PERIODS
    q = CENTRE + A @ sn + B @ (cs - 1.0)
    dq = (A @ (W * cs) - B @ (W * sn)) if moving else np.zeros(7)
    if not acceleration:
        return q, dq
    ddq = -(A @ (W ** 2 * sn) + B @ (W ** 2 * cs)) if moving else np.zeros(7)
    return q, dq, ddq


def approach_time(q_from):
    """Duration of a quintic move to the centre pose at 20 % of the velocity and acceleration limits."""
    d = np.abs(CENTRE - np.asarray(q_from))
    return float(max(1.0, np.max(1.875 * d / (0.2 * DQ_MAX)), np.max(np.sqrt(5.774 * d / (0.2 * DDQ_MAX)))))


def approach(q_from, T, t):
    s = min(max(t / T, 0.0), 1.0)
    return np.asarray(q_from) + (CENTRE - np.asarray(q_from)) * (10 * s ** 3 - 15 * s ** 4 + 6 * s ** 5)


def log_path():
    """A new file next to this script: nothing recorded before is overwritten."""
    base = Path(__file__).resolve().with_name(Path(__file__).stem.replace("play_", "") + "_recorded")
    k = 0
    while True:
        p = base.with_name(base.name + (f"_{{k}}" if k else "") + ".csv")
        if not p.exists() and not p.with_name(p.name + ".json").exists():
            return p
        k += 1
'''

PYLIBFRANKA_SCRIPT = '''"""Play the designed excitation on a Franka robot with pylibfranka (joint position control
through the robot's internal joint impedance controller) and record the robot state for the workbench.

    python {name} ROBOT_ADDRESS

First a smooth move to the excitation's centre pose (20 % of the limits), then the excitation ({duration:.1f} s);
the recorded states of the excitation go to <this script's name without play_>_recorded.csv (+ .json sidecar), a
new file each run. Read it with: franka-vs diagnose FILE; franka-vs fit FILE --add EFFECTS -o model.json.
Designed by franka-vs excite for: {effects}. The same script runs against 'franka-vs serve' and a real robot.
"""
import json
import math
import sys
from pathlib import Path

import numpy as np
import pylibfranka

from franka_vs_gym.validation.readers.robot_states import StateRecorder
{motion_code}

def main():
    if len(sys.argv) != 2:
        sys.exit("usage: python {name} ROBOT_ADDRESS")
    out = log_path()
    robot = pylibfranka.Robot(sys.argv[1], pylibfranka.RealtimeConfig.kIgnore)
    rec = StateRecorder(seconds=DURATION + 2)
    control = robot.start_joint_position_control(pylibfranka.ControllerMode.JointImpedance)
    t, q_start, T_move = 0.0, None, None
    while True:
        state, period = control.readOnce()
        if q_start is None:
            q_start = np.array(state.q_d)
            T_move = approach_time(q_start)
        t += period.to_sec()
        if t <= T_move:
            q = approach(q_start, T_move, t)
        else:
            rec(state)
            q, _ = excitation(t - T_move)
        cmd = pylibfranka.JointPositions(q.tolist())
        cmd.motion_finished = t >= T_move + DURATION
        control.writeOnce(cmd)
        if cmd.motion_finished:
            break
    rec.save(out)
    print(json.dumps({{"log": str(out), "samples": rec.n, "dropped": rec.dropped}}))


if __name__ == "__main__":
    main()
'''

FRANKY_SCRIPT = '''"""Play the designed excitation on a Franka robot with franky and record the robot state.

    python {name} ROBOT_ADDRESS

First a move to the excitation's centre pose (franky's JointMotion), then the excitation ({duration:.1f} s) as a
joint reference read every control cycle by franky's JointImpedanceTrackingMotion: the designed position and
velocity at the robot's own time, and the designed acceleration through the robot model's mass matrix as feed-forward
torque (a JointWaypointMotion would reach each waypoint at zero acceleration: a ripple at the waypoint rate in the
torques, which a lower-rate recording folds into the motion band). The recorded states go to <this script's name
without play_>_recorded.csv (+ .json sidecar), a new file each run. Read it with: franka-vs diagnose FILE;
franka-vs fit FILE --add EFFECTS -o model.json. Designed by franka-vs excite for: {effects}. The same script runs
against 'franka-vs serve' and a real robot.
"""
import json
import math
import sys
from pathlib import Path

import numpy as np
from franky import (JointImpedanceTrackingMotion, JointMotion, JointReference, Measure, RealtimeConfig,
                    RelativeDynamicsFactor, Robot, TorqueReaction, TorqueStopMotion)

from franka_vs_gym.validation.readers.robot_states import StateRecorder
{motion_code}
STIFFNESS = [600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0]  # Nm/rad (the gains of libfranka's joint impedance
DAMPING = [50.0, 50.0, 50.0, 20.0, 20.0, 20.0, 10.0]  # Nm s/rad   example)


def main():
    if len(sys.argv) != 2:
        sys.exit("usage: python {name} ROBOT_ADDRESS")
    out = log_path()
    robot = Robot(sys.argv[1], realtime_config=RealtimeConfig.Ignore)
    robot.relative_dynamics_factor = RelativeDynamicsFactor(0.2, 0.2, 0.2)
    robot.move(JointMotion(CENTRE.tolist()))
    model = robot.model
    motion = JointImpedanceTrackingMotion(stiffness=STIFFNESS, damping=DAMPING)
    rec = StateRecorder(seconds=DURATION + 5)

    def reference(state, t):
        q, dq, ddq = excitation(t, acceleration=True)
        return JointReference(q.tolist(), dq.tolist(), (model.mass(state) @ ddq).tolist())

    def step(state, dt, rel, abs_time, tau):  # every cycle: record, and the reference for the next one
        rec(state)
        motion.set_reference(reference(state, rel.to_sec() + 0.001))

    motion.set_reference(reference(robot.state, 0.0))
    motion.register_callback(step)
    motion.add_reaction(TorqueReaction(Measure.REL_TIME > DURATION, TorqueStopMotion()))  # then brought to rest
    robot.move(motion)
    rec.save(out)
    print(json.dumps({{"log": str(out), "samples": rec.n, "dropped": rec.dropped}}))


if __name__ == "__main__":
    main()
'''


def scripts(design: Design, stem: str = "excitation") -> dict[str, str]:
    """The pylibfranka and franky scripts that play the design (file name -> text)."""
    from franka_vs_gym.model.franka_model import FrankaModel

    lim = FrankaModel().limits()
    motion = json.dumps(design.motion.to_dict())
    code = _MOTION_CODE.format(motion=motion, dq_max=lim["dq_max"].tolist(), ddq_max=lim["ddq_max"].tolist())
    eff = ", ".join(design.effects)
    out = {}
    n1, n2 = f"play_{stem}_pylibfranka.py", f"play_{stem}_franky.py"
    out[n1] = PYLIBFRANKA_SCRIPT.format(name=n1, duration=design.motion.duration, effects=eff, motion_code=code)
    out[n2] = FRANKY_SCRIPT.format(name=n2, duration=design.motion.duration, effects=eff, motion_code=code)
    return out


__all__ = ["scripts", "trajectory_csv", "trajectory_table"]
