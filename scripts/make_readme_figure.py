#!/usr/bin/env python
"""Make docs/images/hero.png: the simulated FER at the start of an IBVS run onto an AprilTag (left)
beside its wrist camera 0.6 s later: detected corners (green), their paths (yellow), goal corners (red).

    python scripts/make_readme_figure.py [--seed 1] [--out docs/images/hero.png] [--force]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import mujoco
import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="docs/images/hero.png")
    ap.add_argument("--force", action="store_true", help="overwrite an existing figure")
    args = ap.parse_args()
    out = Path(args.out)
    if out.exists() and not args.force:
        raise SystemExit(f"{out} exists; pass --force to replace it")
    import imageio.v2 as imageio

    from franka_vs_gym.experiments import servo
    from franka_vs_gym.vision import CameraIntrinsics

    intr = CameraIntrinsics.default(480, 360)
    res = servo.run_servo("ibvs", args.seed, features="detect", intrinsics=intr, record_frames=True, duration=0.6)
    camera_view = res.frames[-1]
    # the scene at the same instant, from a free camera looking at the gripper and the tag
    sim, fMo, *_ = servo.setup(args.seed, intrinsics=intr)
    sim.reset(sim.get_position())
    world = sim.world
    r = world.renderer(480, 360)
    cam = mujoco.MjvCamera()
    cam.lookat[:] = [0.30, 0.0, 0.30]
    cam.distance, cam.azimuth, cam.elevation = 1.75, 140.0, -20.0
    r.update_scene(world.data, cam)
    scene = r.render().copy()
    pad = np.full((360, 8, 3), 255, np.uint8)
    imageio.imwrite(out, np.hstack([scene, pad, camera_view]))
    print(out)


if __name__ == "__main__":
    main()
