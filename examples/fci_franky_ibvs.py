#!/usr/bin/env python
"""IBVS through franky: joint velocities streamed to the (simulated) FER while its wrist camera watches an AprilTag.

The FCI server runs in this process (``FCIServer``) so the script can read the simulated wrist camera, the
counterpart of reading a camera that sits beside the real robot; everything else is what the script would do with
the real robot at 172.16.0.2: franky's ``Robot`` and ``JointVelocityMotion`` (re-issued at every camera frame,
each preempting the previous one), the joint positions from ``robot.current_joint_positions``, the Jacobian from a
model of the arm. The servo law is the project's IBVS (4 tag corners, MEAN interaction matrix, adaptive gain).

    python examples/fci_franky_ibvs.py [--seed 3] [--max-time 8] [--lockstep] [--json]

Real-time mode: the plant runs at 1 kHz of wall time, as the robot does, while this process renders, detects the
tag and computes the next velocity at its own pace (about 50-100 Hz).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from franky import Duration, JointVelocityMotion, RealtimeConfig, Robot

from franka_vs_gym.assets.mjcf import TagSpec
from franka_vs_gym.control.visual_servo import InteractionMatrixType, camera_to_joint_velocity, ibvs_velocity
from franka_vs_gym.experiments.servo import TAG_POS, setup
from franka_vs_gym.fci import FCIServer
from franka_vs_gym.model import FrankaModel
from franka_vs_gym.vision import CameraIntrinsics, TagDetector, detected_measurement, ideal_measurement
from franka_vs_gym.vision.camera import set_mujoco_camera

TAG_SIZE = 0.08


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=3, help="random start pose of the study (experiments.servo)")
    ap.add_argument("--max-time", type=float, default=8.0, help="give up after this many seconds of robot time")
    ap.add_argument("--host", default="127.0.0.1", help="address of the in-process server")
    ap.add_argument("--lockstep", action="store_true",
                    help="lock-step server (the robot runs as fast as franky commands it; for tests)")
    ap.add_argument("--json", action="store_true", help="print the corner-error history as JSON")
    args = ap.parse_args()

    intr = CameraIntrinsics.default()  # 320 x 240
    start, fMo, cdMo, _, _ = setup(args.seed, tag_size=TAG_SIZE, intrinsics=intr)
    goal = ideal_measurement(cdMo, TAG_SIZE, intr)
    tags = [TagSpec(tag_id=0, size=TAG_SIZE, pos=TAG_POS)]
    with FCIServer(args.host, lockstep=args.lockstep, q0=start.get_position(), tags=tags,
                   verbose=not args.json) as server:
        with server.lock:
            set_mujoco_camera(server.sim.world.model, server.sim.camera_name(), intr)
        eMc = server.sim.get_eMc()
        robot = Robot(server.host, realtime_config=RealtimeConfig.Ignore)
        robot.relative_dynamics_factor = 0.5
        model, detector = FrankaModel(), TagDetector()
        history, t0, t_robot0, err_px = [], time.perf_counter(), server.sim.get_time(), np.inf
        while server.sim.get_time() - t_robot0 < args.max_time and time.perf_counter() - t0 < 20 * args.max_time:
            image = server.render_camera(intr.width, intr.height)
            meas = detected_measurement(image, detector, 0, TAG_SIZE, intr)
            if not meas.visible:
                break
            err_px = float(np.abs(meas.corners_px - goal.corners_px).max())
            history.append([time.perf_counter() - t0, server.sim.get_time(), err_px])
            if err_px < 1.0:
                break
            v_c, _ = ibvs_velocity(meas.corners_xy.ravel(), goal.corners_xy.ravel(), meas.depths, goal.depths,
                                   InteractionMatrixType.MEAN)
            dq = camera_to_joint_velocity(v_c, model.eJe(robot.current_joint_positions), eMc)
            dq *= min(1.0, 0.8 / max(np.abs(dq).max(), 1e-9))  # stay well below the joint velocity limits
            robot.move(JointVelocityMotion(dq, duration=Duration(200)), asynchronous=True)
        robot.move(JointVelocityMotion(np.zeros(7), duration=Duration(50)))
        robot.join_motion()
    if args.json:
        print(json.dumps({"history": history, "final_error_px": err_px}))
    else:
        print(f"IBVS through franky: corner error {history[0][2]:.1f} px -> {err_px:.2f} px in "
              f"{history[-1][1] - history[0][1]:.2f} s of robot time ({len(history)} camera frames)")


if __name__ == "__main__":
    main()
