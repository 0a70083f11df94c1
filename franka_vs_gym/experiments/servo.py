"""Visual servoing of the simulated FER's wrist camera onto an AprilTag: ``franka-vs demo ibvs|pbvs`` and the
convergence study (``scripts/eval_servo.py``).

The robot runs in VELOCITY control at 1 kHz; the camera delivers a frame every ``camera_period`` (20 ms by
default), from which the tag is measured (rendered image + AprilTag detection + PnP, or the fast "ideal features"
projection) and the scripted policy (:class:`franka_vs_gym.policies.IBVSPolicy` /
:class:`~franka_vs_gym.policies.PBVSPolicy`) computes a new joint-velocity command, held until the next frame, as on
the real robot with ViSP.

Goal: the tag centred and parallel to the image plane, ``desired_distance`` (0.20 m) in front of the camera. Start:
the camera displaced from the goal by up to ``max_offset`` (0.15 m) and rotated by up to ``max_angle_deg`` (30 deg)
about a random axis, with the whole tag in view including its white quiet zone (which a detector needs), 5 px from
the image border, and the arm within its joint limits.
Convergence: IBVS when every corner is within 1 px of its desired position (true projection); PBVS when the camera
pose is within 1 mm and 0.5 deg of the goal.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from franka_vs_gym.assets.mjcf import TagSpec
from franka_vs_gym.assets.textures import BORDER_CELLS, TAG_CELLS
from franka_vs_gym.model.geometry import desired_tag_pose, inverse_pose, pose_vector
from franka_vs_gym.sim import JOINT_STATE, VELOCITY, FrankaSim
from franka_vs_gym.vision import (
    CameraIntrinsics,
    TagDetector,
    WristCamera,
    detected_measurement,
    ideal_measurement,
)

TAG_POS = (0.50, 0.0, 0.0)
OUTER_SCALE = (TAG_CELLS + 2 * BORDER_CELLS) / TAG_CELLS  # white quiet zone around the black square
PX_TOL = 1.0  # IBVS success: corner error, pixels
T_TOL, R_TOL_DEG = 1e-3, 0.5  # PBVS success: camera pose error


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    import pinocchio as pin

    return np.asarray(pin.exp3(axis / np.linalg.norm(axis) * angle))


def desired_pose(distance: float) -> np.ndarray:
    """cdMo: tag centred, parallel, ``distance`` m in front of the camera (:func:`~franka_vs_gym.model.geometry.
    desired_tag_pose`)."""
    return desired_tag_pose(distance)


@dataclass
class ServoResult:
    """Outcome of one servoing run. Errors are of the true (not measured) tag projection / camera pose."""

    kind: str
    seed: int
    converged: bool
    time_to_converge: float  # s, nan if not converged
    final_corner_error_px: float
    final_translation_error_m: float
    final_rotation_error_deg: float
    start_offset_m: float
    start_angle_deg: float
    t: np.ndarray = field(repr=False)
    corner_error_px: np.ndarray = field(repr=False)
    pose_error: np.ndarray = field(repr=False)  # (n, 2): translation m, rotation deg
    v_c: np.ndarray = field(repr=False)  # (n, 6) camera twist realised
    dq: np.ndarray = field(repr=False)  # (n, 7) joint velocity commands
    frames: list = field(default_factory=list, repr=False)
    detections: int = 0

    def summary(self) -> dict:
        return {k: getattr(self, k) for k in ("kind", "seed", "converged", "time_to_converge",
                                               "final_corner_error_px", "final_translation_error_m",
                                               "final_rotation_error_deg", "start_offset_m", "start_angle_deg",
                                               "detections")}


def _draw(image: np.ndarray, meas, desired_px: np.ndarray, trail: list[np.ndarray]) -> np.ndarray:
    import cv2

    img = np.ascontiguousarray(image.copy())
    for c in desired_px:
        cv2.drawMarker(img, (int(round(c[0])), int(round(c[1]))), (230, 30, 30), cv2.MARKER_CROSS, 10, 1)
    for k in range(4):
        pts = np.array([p[k] for p in trail], dtype=np.int32)
        if len(pts) > 1:
            cv2.polylines(img, [pts], False, (250, 200, 0), 1)
    if meas.visible:
        pts = meas.corners_px.astype(np.int32)
        cv2.polylines(img, [pts], True, (20, 220, 20), 1)
        for c in pts:
            cv2.circle(img, (int(c[0]), int(c[1])), 3, (20, 220, 20), -1)
    return img


def setup(seed: int, *, tag_size: float = 0.08, desired_distance: float = 0.20, max_offset: float = 0.15,
          max_angle_deg: float = 30.0, intrinsics: CameraIntrinsics | None = None,
          render: bool = False, robot: Any = None) -> tuple[FrankaSim, np.ndarray, np.ndarray, float, float]:
    """A simulated arm (``robot``, the FER by default) with a tag on the table, at a seeded random start. Returns
    (sim, fMo, cdMo, offset, angle). The start satisfies the study's constraints (tag and quiet zone in view, joints
    within limits)."""
    intr = intrinsics or CameraIntrinsics.default()
    sim = FrankaSim(tags=[TagSpec(tag_id=0, size=tag_size, pos=TAG_POS)], camera=True, robot=robot)
    fMo = np.eye(4)
    fMo[:3, 3] = TAG_POS
    cdMo = desired_pose(desired_distance)
    cMe = inverse_pose(sim.get_eMc())
    fMe_goal = fMo @ inverse_pose(cdMo) @ cMe
    q_goal = sim.model.inverse_kinematics(fMe_goal, sim.get_position())
    rng = np.random.default_rng(seed)
    lim = sim.model.limits()
    for _ in range(200):
        direction = rng.normal(size=3)
        offset = max_offset * rng.uniform() ** (1 / 3)  # uniform in the ball
        angle = math.radians(max_angle_deg) * rng.uniform()
        cdMc = np.eye(4)
        cdMc[:3, :3] = _rot(rng.normal(size=3), angle) if angle > 0 else np.eye(3)
        cdMc[:3, 3] = direction / np.linalg.norm(direction) * offset
        cMo = inverse_pose(cdMc) @ cdMo
        # detectable: the tag with its white quiet zone inside the image, 5 px from the border
        if not ideal_measurement(cMo, tag_size * OUTER_SCALE, intr, margin_px=5).visible:
            continue
        try:
            q0 = sim.model.inverse_kinematics(fMo @ inverse_pose(cMo) @ cMe, q_goal, restarts=0, tol=1e-8)
        except ValueError:
            continue
        if (q0 > lim["q_min"] + 0.05).all() and (q0 < lim["q_max"] - 0.05).all():
            sim.reset(q0)
            return sim, fMo, cdMo, float(offset), math.degrees(angle)
    raise RuntimeError(f"seed {seed}: no valid start pose found")


def _check_servo_settings(kind: str, features: str, duration: float, camera_period: float) -> None:
    if kind not in ("ibvs", "pbvs"):
        raise ValueError(f"kind must be 'ibvs' or 'pbvs', got {kind!r}")
    if features not in ("ideal", "detect"):
        raise ValueError(f"features must be 'ideal' or 'detect', got {features!r}")
    if not (duration > 0 and camera_period > 0):
        raise ValueError("duration and camera_period must be > 0 s")


def _measure_tag(cMo_true: np.ndarray, tag_size: float, intr: CameraIntrinsics, camera: WristCamera | None,
                 detector: TagDetector | None, record_frames: bool):
    """One camera frame: (the true projection, the measurement the policy sees, the image or None). With a detector
    the measurement comes from the rendered image, else it is the true projection ("ideal" features)."""
    truth = ideal_measurement(cMo_true, tag_size, intr)
    if detector is not None:
        assert camera is not None
        image, _ = camera.image()
        return truth, detected_measurement(image, detector, 0, tag_size, intr), image
    image = camera.image()[0] if (record_frames and camera is not None) else None
    return truth, truth, image


def _goal_errors(kind: str, truth, desired, cdMo: np.ndarray, cMo_true: np.ndarray) -> tuple[float, float, float,
                                                                                              bool]:
    """(max corner error px, translation error m, rotation error deg, converged) of the true camera pose."""
    err_px = (float(np.max(np.linalg.norm(truth.corners_px - desired.corners_px, axis=1)))
              if truth.visible else math.inf)
    cdMc = cdMo @ inverse_pose(cMo_true)
    t_err = float(np.linalg.norm(cdMc[:3, 3]))
    r_err = math.degrees(float(np.linalg.norm(pose_vector(cdMc)[3:])))
    ok = err_px < PX_TOL if kind == "ibvs" else (t_err < T_TOL and r_err < R_TOL_DEG)
    return err_px, t_err, r_err, ok


def run_servo(kind: str, seed: int, *, features: str = "ideal", duration: float = 10.0, camera_period: float = 0.02,
              intrinsics: CameraIntrinsics | None = None, tag_size: float = 0.08, desired_distance: float = 0.20,
              max_offset: float = 0.15, max_angle_deg: float = 30.0, record_frames: bool = False,
              hold: float = 0.3, show_progress: bool = False, interaction: str = "MEAN",
              robot: Any = None) -> ServoResult:
    """Run IBVS or PBVS on ``robot`` (the FER by default) from a seeded start; stops ``hold`` s after convergence or
    at ``duration``."""
    from franka_vs_gym.policies import IBVSPolicy, PBVSPolicy

    _check_servo_settings(kind, features, duration, camera_period)
    intr = intrinsics or CameraIntrinsics.default()
    sim, fMo, cdMo, offset, angle = setup(seed, tag_size=tag_size, desired_distance=desired_distance,
                                          max_offset=max_offset, max_angle_deg=max_angle_deg, intrinsics=intr,
                                          robot=robot)
    policy = (IBVSPolicy(interaction=interaction, tag_size=tag_size, eMc=sim.get_eMc(), model=sim.model)
              if kind == "ibvs" else PBVSPolicy(eMc=sim.get_eMc(), model=sim.model))
    camera = WristCamera(sim, intr, camera_period) if (features == "detect" or record_frames) else None
    detector = TagDetector() if features == "detect" else None
    desired = ideal_measurement(cdMo, tag_size, intr)
    obs_const = {"features_desired": desired.corners_xy.ravel(), "tag_pose_desired": pose_vector(cdMo)}
    n_cam = max(1, int(round(camera_period / sim.dt)))
    n_steps = int(round(duration / sim.dt))
    sim.set_robot_state(VELOCITY)
    ts, errs, perrs, vcs, dqs, frames, trail = [], [], [], [], [], [], []
    converged_at, detections = None, 0
    bar = None
    if show_progress:
        from franka_vs_gym.experiments.common import progress

        bar = progress(n_steps, f"{kind} demo")
    try:
        for k in range(n_steps):
            if k % n_cam == 0:
                cMo_true = inverse_pose(sim.get_fMc()) @ fMo
                truth, meas, image = _measure_tag(cMo_true, tag_size, intr, camera, detector, record_frames)
                detections += features == "detect" and meas.visible
                obs = {"q": sim.get_position(), "features": meas.corners_xy.ravel(), "feature_depth": meas.depths,
                       "tag_pose": pose_vector(meas.cMo), "visible": np.array([float(meas.visible)]), **obs_const}
                dq_cmd, _ = policy.predict(obs)
                sim.set_velocity(JOINT_STATE, dq_cmd.astype(np.float64))
                err_px, t_err, r_err, ok = _goal_errors(kind, truth, desired, cdMo, cMo_true)
                if ok and converged_at is None:
                    converged_at = sim.time
                elif not ok:
                    converged_at = None
                ts.append(sim.time)
                errs.append(err_px)
                perrs.append((t_err, r_err))
                vcs.append(sim.get_velocity(3))
                dqs.append(dq_cmd)
                if record_frames and image is not None:
                    if meas.visible:
                        trail.append(meas.corners_px.copy())
                    frames.append(_draw(image, meas, desired.corners_px, trail))
                if converged_at is not None and sim.time - converged_at >= hold:
                    break
            sim.step()
            if bar is not None:
                bar.update()
    finally:
        if bar is not None:
            bar.close()
        sim.world.close()  # free the offscreen renderers (GL contexts) of this run
    return ServoResult(kind, seed, converged_at is not None,
                       float("nan") if converged_at is None else float(converged_at), errs[-1], perrs[-1][0],
                       perrs[-1][1], offset, angle, np.array(ts), np.array(errs), np.array(perrs), np.array(vcs),
                       np.array(dqs), frames, detections)


# ---------------------------------------------------------------------------------------------------- CLI (demo)
def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of ``franka-vs demo ibvs|pbvs`` (added to the demo parser)."""
    p.add_argument("--features", default="detect", choices=["detect", "ideal"],
                   help="servo demos: tag measured by rendering + detection (default) or ideal projection")
    p.add_argument("--camera-period", type=float, default=0.02, help="servo demos: camera period, s (default 0.02)")
    p.add_argument("--width", type=int, default=320, help="servo demos: image width, px (default 320)")
    p.add_argument("--height", type=int, default=240, help="servo demos: image height, px (default 240)")


def main(args: argparse.Namespace, kind: str) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import imageio.v2 as imageio
    import matplotlib.pyplot as plt

    from franka_vs_gym.experiments.common import make_run_dir, write_json

    duration = 10.0 if args.duration is None else float(args.duration)
    if not (duration > 0 and math.isfinite(duration)):
        raise ValueError(f"--duration must be > 0 s, got {duration}")
    width, height = args.width, args.height
    if width < 16 or height < 16:
        raise ValueError(f"image size must be at least 16x16 px, got {width}x{height}")
    out = make_run_dir(f"demo-{kind}", args.out)
    intr = CameraIntrinsics.default(width, height)
    wall = time.perf_counter()
    res = run_servo(kind, args.seed, features=args.features, duration=duration, camera_period=args.camera_period,
                    intrinsics=intr, record_frames=not args.no_video, show_progress=not args.quiet,
                    robot=getattr(args, "robot", None))
    wall = time.perf_counter() - wall
    fig, ax = plt.subplots(3, 1, figsize=(9, 10), sharex=True)
    if kind == "ibvs":
        ax[0].semilogy(res.t, np.maximum(res.corner_error_px, 1e-3))
        ax[0].axhline(PX_TOL, color="k", ls="--", lw=0.8, label="1 px")
        ax[0].set_ylabel("max corner error (px)")
    else:
        ax[0].semilogy(res.t, np.maximum(res.pose_error[:, 0] * 1000, 1e-4), label="translation (mm)")
        ax[0].semilogy(res.t, np.maximum(res.pose_error[:, 1], 1e-4), label="rotation (deg)")
        ax[0].axhline(1.0, color="k", ls="--", lw=0.8)
        ax[0].axhline(0.5, color="k", ls=":", lw=0.8)
    ax[0].legend(fontsize=8)
    ax[0].set_title(f"{kind.upper()} of the simulated FER (seed {args.seed}, {args.features} features)")
    labels = ["vx", "vy", "vz", "wx", "wy", "wz"]
    for i in range(6):
        ax[1].plot(res.t, res.v_c[:, i], label=labels[i])
    ax[1].set_ylabel("camera twist (m/s, rad/s)")
    ax[1].legend(ncol=6, fontsize=8)
    for j in range(7):
        ax[2].plot(res.t, res.dq[:, j], label=f"dq[{j}]")
    ax[2].set_ylabel("joint velocity command (rad/s)")
    ax[2].set_xlabel("time (s)")
    ax[2].legend(ncol=7, fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "servo.png", dpi=90)
    plt.close(fig)
    if res.frames:
        fps = int(round(1 / args.camera_period))
        imageio.mimsave(out / "camera.mp4", res.frames, fps=fps, macro_block_size=8)
        imageio.imwrite(out / "camera_last.png", res.frames[-1])
    metrics = res.summary() | {"features": args.features, "camera_period_s": args.camera_period,
                               "image_size": [width, height], "wall_time_s": wall,
                               "simulated_time_s": float(res.t[-1]) if len(res.t) else 0.0}
    write_json(out / "metrics.json", metrics)
    verdict = (f"converged in {res.time_to_converge:.2f} s" if res.converged else "did NOT converge")
    print(f"demo {kind}: {verdict}; final corner error {res.final_corner_error_px:.3f} px, pose error "
          f"{res.final_translation_error_m * 1000:.3f} mm / {res.final_rotation_error_deg:.3f} deg; outputs in {out}",
          file=sys.stderr)
    print(out)
    return 0 if res.converged else 1
