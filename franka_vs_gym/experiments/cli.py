"""``franka-vs experiment``: the FrankaSim paper's experiments, replicated.

- ``franka-vs experiment tracking``: IV-A, joint trajectory tracking with computed torque eq. (2) at 1 kHz.
- ``franka-vs experiment dual-arm``: IV-B, the dual-arm "Franko": a torque-controlled arm holding an AprilTag on a
  circle, followed by a velocity-controlled arm running PBVS with a visual admittance law that meets an obstacle.

Each run writes into a new folder ``<out>/<name>-<UTC timestamp>/`` (never an existing one) and shows progress on
stderr.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

from franka_vs_gym.errors import UserError
from franka_vs_gym.experiments.common import make_run_dir


def _positive(x: str) -> float:
    v = float(x)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {x}")
    return v


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="experiment", metavar="EXPERIMENT")
    sub.required = True

    def common(p: argparse.ArgumentParser, duration: float) -> None:
        p.add_argument("--duration", type=_positive, default=duration, help=f"simulated seconds (default {duration})")
        p.add_argument("--out", default="runs", help="parent folder of the run folder (default runs/)")
        p.add_argument("--seed", type=int, default=0, help="random seed (measurement noise)")
        p.add_argument("--no-video", action="store_true", help="do not render a video")
        p.add_argument("--quiet", action="store_true", help="no progress bar")

    t = sub.add_parser("tracking", help="IV-A: sinusoidal joint tracking with computed torque eq. (2) at 1 kHz",
                       description="IV-A replica: from q0 = [0, -pi/4, 0, -3pi/4, 0, pi/2, pi/4], sinusoids on "
                       "joints 1, 3, 4; eq. (2) with Kp 400 (900 on joint 7), mu = 4. Writes plots, metrics.json "
                       "(RMSE per joint) and a measurement log in the workbench format.")
    common(t, 15.0)
    t.add_argument("--model-error", choices=("none", "no-friction", "payload"), default="none",
                   help="controller model: exact (none), without friction, or unaware of a 1 kg payload")
    t.add_argument("--log-format", choices=("npz", "csv"), default="npz", help="measurement log format")
    t.add_argument("--torque-noise", type=float, default=0.0, help="std of measured-torque noise, Nm")

    d = sub.add_parser("dual-arm", help="IV-B: dual-arm Franko, circle + PBVS with visual admittance and contact",
                       description="IV-B replica: left FER torque-controlled (gravity compensation, then Cartesian "
                       "computed torque on a 5 cm circle at 0.3 Hz) holding an AprilTag; right FER with wrist "
                       "camera and F/T sensor runs PBVS with a visual admittance law at 0.20 m and hits an "
                       "obstacle. Writes a video, both end-effector paths, the contact force and metrics.")
    common(d, 20.0)
    d.add_argument("--camera-rate", type=_positive, default=30.0, help="camera / PBVS rate, Hz (default 30)")
    d.add_argument("--vision", choices=("ideal", "detect"), default="ideal",
                   help="tag pose from the projected true corners (ideal) or AprilTag detection in rendered "
                        "wrist images (detect; slower)")
    d.add_argument("--no-obstacle", action="store_true", help="remove the obstacle (path stays a circle)")
    d.add_argument("--pixel-noise", type=float, default=0.0,
                   help="std of pixel noise on the ideal tag corners, px (pose then estimated by PnP; uses --seed)")


def main(args: argparse.Namespace) -> int:
    progress = not args.quiet
    if args.experiment == "tracking":
        from franka_vs_gym.experiments.tracking import run_tracking, write_tracking

        if not (math.isfinite(args.torque_noise) and args.torque_noise >= 0):  # refused before a run folder exists
            raise UserError(f"--torque-noise must be a finite number >= 0 Nm (standard deviation), got "
                            f"{args.torque_noise}")
        folder = make_run_dir("tracking", root=args.out)
        print(f"tracking: writing into {folder}", file=sys.stderr)
        result = run_tracking(args.duration, model_error=args.model_error, torque_noise=args.torque_noise,
                              seed=args.seed, progress=progress,
                              video=None if args.no_video else folder / "video.mp4")
        write_tracking(result, folder, log_format=args.log_format)
        rmse = result.rmse
        print("tracking RMSE per joint [mrad]: " + " ".join(f"{1e3 * r:.3f}" for r in rmse))
        print(f"run folder: {folder}")
        return 0
    if args.experiment == "dual-arm":
        from franka_vs_gym.experiments.dual_arm import run_dual_arm, write_dual_arm

        folder = make_run_dir("dual-arm", root=args.out)
        print(f"dual-arm: writing into {folder}", file=sys.stderr)
        dual = run_dual_arm(args.duration, camera_rate=args.camera_rate, vision=args.vision,
                            obstacle=not args.no_obstacle, pixel_noise=args.pixel_noise, seed=args.seed,
                            progress=progress,
                            video=None if args.no_video else folder / "video.mp4")
        write_dual_arm(dual, folder)
        m = dual.metrics()
        keys = ("circle_rmse_m", "pbvs_translation_rmse_m", "contact_force_peak_n")
        print("dual-arm: " + json.dumps({k: m[k] for k in keys if k in m}))
        print(f"run folder: {folder}")
        return 0
    raise ValueError(f"unknown experiment {args.experiment!r} (choose tracking or dual-arm)")
