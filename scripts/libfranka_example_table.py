#!/usr/bin/env python
"""The example table: each of libfranka's example programs (examples/libfranka) and franky's documented motions run
unmodified in its own process against ``FCIServer``, per robot (FER, FR3) and mode (lock-step, real time), with its
result (pass by the test's criteria, tests/test_libfranka_examples.py ``check``), its wall time and its own worst
tracking error. Real-time rows also give the commands that arrived in their cycle and the cycles the server dropped
(machine too slow; FCIServer.motion_stats) with the machine's load.

    python scripts/libfranka_example_table.py                   # all examples, both robots, both modes (~15 min)
    python scripts/libfranka_example_table.py --modes lockstep --robots fer
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_libfranka_examples import FORCE_Q0, FORCE_TABLE, check, run_example  # noqa: E402

from franka_vs_gym.fci import FCIServer  # noqa: E402

# (example, its arguments, the JSON key of its worst tracking error and the unit)
EXAMPLES = [
    ("echo_robot_state", (), "drift_rad", "rad"),
    ("communication_test", (), "drift_rad", "rad"),
    ("generate_joint_position_motion", (), "worst_tracking_rad", "rad"),
    ("generate_joint_velocity_motion", (), "worst_tracking_rad_s", "rad/s"),
    ("generate_cartesian_pose_motion", (), "worst_tracking_m", "m"),
    ("generate_cartesian_velocity_motion", (), "worst_tracking_m", "m"),
    ("joint_impedance_control", ("--run-time", "5"), "worst_tracking_rad", "rad"),
    ("cartesian_impedance_control", ("--duration", "5"), "worst_drift_m", "m"),
    ("force_control", ("--duration", "10"), "worst_distance_m", "m"),
    ("generate_elbow_motion", (), "worst_drift_m", "m"),
    ("franky_examples", (), "worst_error", "rad or m"),
]


def row(name: str, args: tuple, key: str, robot: str, lockstep: bool, host: str) -> tuple[str, float, str, str]:
    extra = dict(tool="none", table_height=FORCE_TABLE, q0=FORCE_Q0) if name == "force_control" else {}
    with FCIServer(host, lockstep=lockstep, camera=False, verbose=False, robot=robot, **extra) as srv:
        t0 = time.monotonic()
        out = None
        try:
            out = run_example(name, srv.host, *args, timeout=600)
            check(out)
            verdict, err = "pass", f"{out[key]:.3g}"
        except AssertionError as e:  # the reason in one line: the assertion's text, or the example's own numbers
            text = str(e).strip().splitlines()
            why = text[0][:100] if text else ""
            if out is not None:
                why = ", ".join(f"{k} {v:.3g}" for k, v in out.items() if isinstance(v, float) and k != "wall_s")
            verdict, err = "FAIL", why
        wall = time.monotonic() - t0
        stats = srv.motion_stats
    rt = ""
    if not lockstep and stats:
        cyc = sum(s["cycles"] for s in stats)
        rt = (f"{100 * sum(s['in_time'] for s in stats) / max(cyc, 1):.0f} % in cycle, "
              f"{sum(s['server_dropped'] for s in stats)} dropped, load {os.getloadavg()[0]:.1f}")
    return verdict, wall, err, rt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument("--robots", nargs="+", default=["fer", "fr3"])
    ap.add_argument("--modes", nargs="+", default=["lockstep", "realtime"], choices=["lockstep", "realtime"])
    ap.add_argument("--only", nargs="+", help="these examples only")
    ap.add_argument("--host", default="127.0.43.1")
    a = ap.parse_args()
    print("| example | robot | mode | pass | wall time, s | worst tracking error | real time: commands, dropped |")
    print("|---|---|---|---|---|---|---|")
    for name, args, key, unit in EXAMPLES:
        if a.only and name not in a.only:
            continue
        for robot in a.robots:
            for mode in a.modes:
                verdict, wall, err, rt = row(name, args, key, robot, mode == "lockstep", a.host)
                shown = f"{err} {unit}" if verdict == "pass" else err
                print(f"| {name} {' '.join(args)} | {robot.upper()} | {mode} | {verdict} | {wall:.1f} | {shown} | "
                      f"{rt} |", flush=True)


if __name__ == "__main__":
    main()
