"""Speed of the perception pipeline (called by scripts/bench.py)."""

from __future__ import annotations

import timeit

import numpy as np


def bench(quick: bool = False) -> dict[str, str]:
    """Per-frame cost of rendering a 320x240 wrist image and detecting the tag (+ PnP), and of one ideal-features
    call, on one core. Targets: <= 15 ms and <= 0.1 ms."""
    from franka_vs_gym.assets.mjcf import TagSpec
    from franka_vs_gym.sim import FrankaSim
    from franka_vs_gym.vision import CameraIntrinsics, TagDetector, WristCamera, detected_measurement, ideal_measurement

    intr = CameraIntrinsics.default(320, 240)
    sim = FrankaSim(tags=[TagSpec(pos=(0.40, 0.0, 0.0))])
    cam = WristCamera(sim, intr)
    det = TagDetector()
    img = cam.render()
    n = 20 if quick else 200
    t_render = min(timeit.repeat(cam.render, number=n, repeat=3)) / n
    t_detect = min(timeit.repeat(lambda: detected_measurement(img, det, 0, 0.08, intr), number=n, repeat=3)) / n
    cMo = np.eye(4)
    cMo[:3, :3] = np.diag([1.0, -1.0, -1.0])
    cMo[2, 3] = 0.25
    m = 2000 if quick else 20000
    t_ideal = min(timeit.repeat(lambda: ideal_measurement(cMo, 0.08, intr), number=m, repeat=3)) / m
    total = t_render + t_detect
    return {
        "render 320x240 (ms)": f"{t_render * 1e3:.2f}",
        "detect + PnP (ms)": f"{t_detect * 1e3:.2f}",
        "render + detect per frame (ms), target <= 15": f"{total * 1e3:.2f} ({'met' if total <= 15e-3 else 'NOT met'})",
        "ideal features per call (ms), target <= 0.1": f"{t_ideal * 1e3:.4f} "
                                                       f"({'met' if t_ideal <= 1e-4 else 'NOT met'})",
    }
