"""Experiment IV-B of the FrankaSim paper, replicated: the dual-arm "Franko".

Two FERs with Franka Hands on a common base (``left_`` at y = +0.4 m, ``right_`` at y = -0.4 m, both facing +x; world
frame = the common base, z up), stepped synchronously by one :class:`~franka_vs_gym.sim.SimWorld` at 1 kHz.

Left arm, torque control (FORCE_TORQUE, gravity-free commands, the robot adds g of arm + hand):
  1. gravity compensation only (``gc_time`` s): :class:`~franka_vs_gym.control.GravityCompensation` also carries the
     tag holder (0.2 kg), which the robot's own model does not know about (an undeclared payload), plus damping;
  2. reach (``reach_time`` s): :class:`~franka_vs_gym.control.CartesianComputedTorque` along a minimum-jerk path to
     the circle's start pose;
  3. circle: 5 cm radius at 0.3 Hz in the vertical x-z plane, holding an AprilTag 36h11 (8 cm) facing the right arm.
  The controller's model includes the holder: gravity and payload are compensated.

Right arm, velocity control (VELOCITY, camera-frame twists), wrist camera and wrist F/T sensor:
  PBVS keeps the tag centred at 0.20 m in front of the camera (desired cdMo: tag facing the camera, z_o = -z_c).
  The tag pose cMo comes at the camera rate (30 Hz by default) from :mod:`franka_vs_gym.vision`:
  ``vision="ideal"`` projects the true corners with the camera model (no image noise), ``vision="detect"`` renders
  the wrist image and estimates the pose by AprilTag detection and PnP. The PBVS law is
  :func:`franka_vs_gym.control.pbvs_velocity` (e = (t, theta u) of cdMc) with a constant gain, plus a feed-forward
  d_hat of the tag's own velocity (estimated from two successive tag positions in the right robot's base frame,
  low-pass filtered; without it a proportional law lags a moving target by v_target / lambda). Between camera
  frames the PBVS twist is held (and smoothed); at 1 kHz a visual admittance (vision-force) law adds ``A f_c`` (the
  F/T force in the camera frame, so contact pushes the camera away). A box on the table blocks the lowest part of
  the right gripper's path: in contact the gripper slides along its top and its circle becomes a "D".

Outputs (:func:`write_dual_arm`): ``video.mp4`` (overview + right wrist camera), ``paths.png`` (both end-effector
paths in the x-z plane: circle and "D"), ``contact_force.png``, ``pbvs_error.png``, ``metrics.json``.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np

from franka_vs_gym.model.config import ModelConfig, RigidBody
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.model.geometry import CAMERA_VISP_TO_MUJOCO, desired_tag_pose, homogeneous

if TYPE_CHECKING:
    from franka_vs_gym.sim.world import SimWorld

LEFT_BASE = np.array([0.0, 0.4, 0.0])
RIGHT_BASE = np.array([0.0, -0.4, 0.0])
CIRCLE_CENTER = np.array([0.5, 0.0, 0.42])  # of the tag's path, world frame, m
CIRCLE_RADIUS = 0.05  # m
CIRCLE_FREQUENCY = 0.3  # Hz
TAG_SIZE = 0.08  # m, black square
TAG_ID = 0
PBVS_DEPTH = 0.20  # m, camera to tag
TAG_HOLDER = RigidBody(0.2, np.array([0.0, 0.0, 0.12]), np.diag([2e-4, 2e-4, 2e-4]))  # flange frame
# Held tag, world orientation: x_o up, z_o towards the right arm (-y). The left end effector holds it with z_e = z_o
# and x_e down (the tag turned by pi about its normal), the tag 1.2 cm beyond the finger tips.
W_R_TAG = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
eMo_LEFT = np.array([[-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.012], [0.0, 0.0, 0.0, 1.0]])
# Right wrist camera mount (fixed here so the scene does not depend on the library default): optical axis along
# z_e, 6 cm from the fingers along x_e and 6 cm behind the finger tips.
RIGHT_eMc = np.array([[1.0, 0.0, 0.0, 0.06], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, -0.06], [0.0, 0.0, 0.0, 1.0]])
# IK seeds giving comfortable postures (elbow up, far from the joint limits)
Q_SEED_LEFT = np.array([-0.6, 0.0, 0.15, -2.3, -1.9, 1.9, 0.0])
Q_SEED_RIGHT = np.array([0.3, 0.0, -0.2, -2.25, 1.65, 1.66, -1.48])
# Desired tag pose in the right camera: centred, 0.20 m ahead, facing the camera (x_o = x_c, z_o = -z_c).
cdMo = desired_tag_pose(PBVS_DEPTH)
# Obstacle: a box on the table under the lowest part of the right gripper's path (contype 1 / conaffinity 2).
# Its y extent covers the hand and fingers (flange at y ~ -0.24, finger tips at y ~ -0.14) but not link 7; its top
# (0.30 m) is ~1.7 cm above the lowest point the hand reaches when following the circle.
OBSTACLE_POS = np.array([0.5, -0.16, 0.15])
OBSTACLE_HALF = np.array([0.09, 0.05, 0.15])
OBSTACLE_SOLREF = "0.05 1"  # MuJoCo contact time constant (s) and damping ratio: a slightly compliant surface


def _rotvec(R: np.ndarray) -> np.ndarray:
    import pinocchio as pin

    return pin.log3(R)


def _exp(w: np.ndarray) -> np.ndarray:
    import pinocchio as pin

    return pin.exp3(w)


def pbvs_twist(cMo: np.ndarray, cdMo_: np.ndarray, gain: float, target_motion: np.ndarray | None = None) -> np.ndarray:
    """PBVS camera twist [v; w] (6,) in the camera frame c (m/s, rad/s).

    :func:`franka_vs_gym.control.pbvs_velocity` (e = (t, theta u) of cdMc, ``v_c = -gain L^-1 e``) with a constant
    gain (1/s), plus the feed-forward ``target_motion`` (3,): the velocity, in c, of the tag's own translation
    (a camera moving with it keeps cMo constant, whatever the error definition).
    """
    from franka_vs_gym.control.visual_servo import pbvs_velocity

    if not (gain > 0 and math.isfinite(gain)):
        raise ValueError(f"PBVS gain must be > 0, got {gain}")
    v, _ = pbvs_velocity(cMo, cdMo_, float(gain))
    if target_motion is not None:
        v = v.copy()
        v[:3] += target_motion
    return v


def minimum_jerk(t: float, T: float) -> tuple[float, float, float]:
    """s, ds/dt, d2s/dt2 of the quintic 0 -> 1 over [0, T] (s, 1/s, 1/s^2)."""
    if t <= 0:
        return 0.0, 0.0, 0.0
    if t >= T:
        return 1.0, 0.0, 0.0
    x = t / T
    return (10 * x**3 - 15 * x**4 + 6 * x**5, (30 * x**2 - 60 * x**3 + 30 * x**4) / T,
            (60 * x - 180 * x**2 + 120 * x**3) / T**2)


@dataclass
class DualArmResult:
    """Time series of one dual-arm run (world frame, m, N), sampled at ``log_rate`` Hz.

    time (N,) s; phase (N,) int (0 gravity compensation, 1 reach, 2 circle); left_ee, left_ref, right_ee, tag
    (N, 3) positions in the world; pbvs_error (N, 6) [c t_o - cd t_o; theta u(cdRc)] from the true poses (m, rad);
    contact_force (N,) N: total normal+friction force between the obstacle and the right arm (MuJoCo contacts);
    ft_force (N, 3) N: wrist F/T force in the right end-effector frame; visible (N,) bool: tag measured at the last
    camera frame.
    """

    time: np.ndarray
    phase: np.ndarray
    left_ee: np.ndarray
    left_ref: np.ndarray
    right_ee: np.ndarray
    tag: np.ndarray
    pbvs_error: np.ndarray
    contact_force: np.ndarray
    ft_force: np.ndarray
    visible: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)
    gc_drift: float = 0.0
    frames: int = 0

    def metrics(self) -> dict[str, Any]:
        circ = self.phase == 2
        ramp_end = self.settings.get("circle_start_s", 0.0) + self.settings.get("circle_ramp_s", 0.0)
        steady = circ & (self.time >= ramp_end)
        sel = steady if steady.any() else circ
        lerr = np.linalg.norm(self.left_ee - self.left_ref, axis=1)
        et = np.linalg.norm(self.pbvs_error[:, :3], axis=1)
        er = np.linalg.norm(self.pbvs_error[:, 3:], axis=1)
        contact = self.contact_force > 1e-3
        free = sel & ~contact
        incontact = sel & contact
        dt = float(np.median(np.diff(self.time))) if len(self.time) > 1 else 0.0

        def rms(x: np.ndarray, s: np.ndarray) -> float | None:
            return float(np.sqrt(np.mean(x[s] ** 2))) if s.any() else None

        m: dict[str, Any] = {
            "experiment": "dual-arm Franko (FrankaSim paper IV-B replica)",
            "duration_s": float(self.time[-1]) if len(self.time) else 0.0,
            "gravity_compensation_drift_m": self.gc_drift,
            "circle_rmse_m": rms(lerr, sel),
            "circle_max_error_m": float(lerr[sel].max()) if sel.any() else None,
            "pbvs_translation_rmse_m": rms(et, sel),
            "pbvs_translation_rmse_free_m": rms(et, free),
            "pbvs_translation_rmse_contact_m": rms(et, incontact),
            "pbvs_rotation_rmse_rad": rms(er, sel),
            "pbvs_final_translation_error_before_motion_m": None,
            "contact_force_peak_n": float(self.contact_force.max()) if len(self.contact_force) else 0.0,
            "ft_force_peak_n": float(np.linalg.norm(self.ft_force, axis=1).max()) if len(self.ft_force) else 0.0,
            "contact_time_s": float(contact.sum() * dt),
            "tag_visible_fraction": float(np.mean(self.visible)) if len(self.visible) else 0.0,
            "right_path_min_z_m": float(self.right_ee[sel, 2].min()) if sel.any() else None,
            "right_path_flatness_m": None,
            "video_frames": self.frames,
            "settings": self.settings,
        }
        gc = self.phase == 0
        if gc.any():
            m["pbvs_final_translation_error_before_motion_m"] = float(et[gc][-1])
        if sel.any() and self.settings.get("obstacle"):
            # "D": the lowest band of the right end effector's path is flat (pressed on the obstacle's top)
            z = self.right_ee[sel, 2]
            low = z <= z.min() + 0.005
            m["right_path_flatness_m"] = float(np.ptp(self.right_ee[sel][low, 0]))
        return m


class _TagMeasurement:
    """cMo of the held tag at the camera rate, with :mod:`franka_vs_gym.vision`: ideal (the true corners projected
    with the camera model, visible when all four are in the image and the tag faces the camera) or detected
    (the right wrist camera's rendered image, AprilTag detection, IPPE-square PnP)."""

    def __init__(self, world: Any, right: Any, mode: str, width: int = 640, height: int = 480,
                 period: float = 1.0 / 30.0, noise_px: float = 0.0, seed: int = 0) -> None:
        from franka_vs_gym.vision import CameraIntrinsics, TagDetector, WristCamera

        if mode not in ("ideal", "detect"):
            raise ValueError(f"vision must be 'ideal' or 'detect', got {mode!r}")
        m = world.model
        self.world, self.right, self.mode = world, right, mode
        self.tag_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "tag")
        self.cam = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, right.camera_name())
        self.intrinsics = CameraIntrinsics.from_fovy(width, height, float(m.cam_fovy[self.cam]))
        self.camera = WristCamera(right, self.intrinsics, period) if mode == "detect" else None
        self.detector = TagDetector() if mode == "detect" else None
        if not (noise_px >= 0 and math.isfinite(noise_px)):
            raise ValueError(f"pixel noise must be a finite number >= 0 px, got {noise_px}")
        self.noise_px = float(noise_px)
        self.rng = np.random.default_rng(seed)

    def true_cMo(self) -> np.ndarray:
        d = self.world.data
        wMo = homogeneous(d.xmat[self.tag_body].reshape(3, 3), d.xpos[self.tag_body])
        wMc = homogeneous(d.cam_xmat[self.cam].reshape(3, 3) @ CAMERA_VISP_TO_MUJOCO, d.cam_xpos[self.cam])
        return np.linalg.inv(wMc) @ wMo

    def measure(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(cMo or None when the tag is not seen, the rendered image or None)."""
        from franka_vs_gym.vision import detected_measurement, estimate_pose, ideal_measurement

        if self.camera is None or self.detector is None:
            meas = ideal_measurement(self.true_cMo(), TAG_SIZE, self.intrinsics, noise_px=self.noise_px,
                                     rng=self.rng)
            if meas.visible and self.noise_px > 0:
                # the pose the camera would estimate from the noisy corners
                return estimate_pose(meas.corners_px, TAG_SIZE, self.intrinsics), None
            return (meas.cMo if meas.visible else None), None
        img = self.camera.render()
        meas = detected_measurement(img, self.detector, TAG_ID, TAG_SIZE, self.intrinsics)
        return (meas.cMo if meas.visible else None), img


def build_world(obstacle: bool = True, timestep: float = 0.001):
    """The Franko scene and its two robots: (world, left FrankaSim, right FrankaSim, left controller model).

    The left robot's own model is FER + hand (the holder is an undeclared payload to it); the returned controller
    model adds the holder (``TAG_HOLDER``) as a payload.
    """
    from franka_vs_gym.assets.mjcf import ENV_COLLISION, VISUAL_ONLY, RobotSpec, SceneSpec, TagSpec, mat2quat
    from franka_vs_gym.sim.robot import FrankaSim
    from franka_vs_gym.sim.world import SimWorld

    cfg = ModelConfig()
    flMe = cfg.tool.flMe
    flMo = flMe @ eMo_LEFT
    tag = TagSpec(tag_id=TAG_ID, size=TAG_SIZE, pos=tuple(flMo[:3, 3]), quat=tuple(mat2quat(flMo[:3, :3])),
                  parent="left_hand", name="tag")
    extra = [f'<geom name="franko_torso" type="box" size="0.12 0.55 0.04" pos="-0.05 0 -0.0" '
             f'rgba="0.25 0.27 0.3 1" {VISUAL_ONLY}/>',
             '<camera name="franko_view" pos="1.45 -0.95 0.95" xyaxes="0.55 0.835 0 -0.38 0.25 0.89" fovy="45"/>']
    if obstacle:
        extra.append(f'<geom name="obstacle" type="box" size="{OBSTACLE_HALF[0]} {OBSTACLE_HALF[1]} '
                     f'{OBSTACLE_HALF[2]}" pos="{OBSTACLE_POS[0]} {OBSTACLE_POS[1]} {OBSTACLE_POS[2]}" '
                     f'rgba="0.8 0.35 0.2 1" {ENV_COLLISION} friction="0.2 0.005 0.0001" solref="{OBSTACLE_SOLREF}"/>')
    scene = SceneSpec(
        robots=[RobotSpec(prefix="left_", base_pos=tuple(LEFT_BASE), config=cfg, camera=False,
                          undeclared_payload=TAG_HOLDER),
                RobotSpec(prefix="right_", base_pos=tuple(RIGHT_BASE), config=ModelConfig(), camera=True,
                          ft_sensor=True)],
        table=True, tags=[tag], timestep=timestep, extra_worldbody="\n".join(extra))
    world = SimWorld(scene)
    q_left, q_right = initial_configurations()
    left = FrankaSim(world=world, prefix="left_", q0=q_left)
    right = FrankaSim(world=world, prefix="right_", q0=q_right)
    right.set_eMc(RIGHT_eMc)
    world.forward()  # camera poses in the data follow the new mount before the first frame
    ctrl_model = FrankaModel(cfg.copy(payload=TAG_HOLDER))
    return world, left, right, ctrl_model


def circle_start_pose() -> np.ndarray:
    """World pose (4, 4) of the left end effector when the tag is at the circle's start (top of the circle)."""
    p_tag = CIRCLE_CENTER + np.array([0.0, 0.0, CIRCLE_RADIUS])
    return homogeneous(W_R_TAG, p_tag) @ np.linalg.inv(eMo_LEFT)


# pose of the left end effector before the reach: 8 cm back (-x) and 2 cm above the circle start, so the right hand
# following the tag starts well clear of the obstacle
REACH_OFFSET = np.array([-0.08, 0.0, 0.02])


def initial_configurations() -> tuple[np.ndarray, np.ndarray]:
    """Joint positions (7,) of the left arm (at the pre-reach pose) and of the right arm (camera 0.2 m from the
    tag, 2 cm and a few degrees off the PBVS goal, so PBVS has something to do during gravity compensation)."""
    m = FrankaModel()
    wMe_l = circle_start_pose()
    wMe_l[:3, 3] += REACH_OFFSET
    fMe_l = wMe_l.copy()
    fMe_l[:3, 3] -= LEFT_BASE
    q_l = m.inverse_kinematics(fMe_l, Q_SEED_LEFT)
    wMo = wMe_l @ eMo_LEFT
    off = homogeneous(_exp(np.array([0.0, 0.05, 0.03])), [0.02, -0.015, 0.01])
    wMc = wMo @ np.linalg.inv(cdMo) @ off
    wMe_r = wMc @ np.linalg.inv(RIGHT_eMc)
    fMe_r = wMe_r.copy()
    fMe_r[:3, 3] -= RIGHT_BASE
    q_r = m.inverse_kinematics(fMe_r, Q_SEED_RIGHT)
    return q_l, q_r


def _check_dual_arm_settings(duration: float, camera_rate: float, pbvs_gain: float, log_rate: float, vision: str,
                             **nonneg: float) -> None:
    for name, v in (("duration", duration), ("camera_rate", camera_rate), ("pbvs_gain", pbvs_gain),
                    ("log_rate", log_rate)):
        if not (v > 0 and math.isfinite(v)):
            raise ValueError(f"{name} must be a finite number > 0, got {v}")
    for name, v in nonneg.items():
        if not (v >= 0 and math.isfinite(v)):
            raise ValueError(f"{name} must be a finite number >= 0, got {v}")
    if vision not in ("ideal", "detect"):
        raise ValueError(f"vision must be 'ideal' or 'detect', got {vision!r}")


class _LeftArm:
    """The left arm's 1 kHz torque loop: gravity compensation (phase 0), a minimum-jerk reach to the circle's start
    (phase 1), then the circle (phase 2), with Cartesian computed torque on the controller's model."""

    def __init__(self, left, ctrl_model: FrankaModel, dt: float, gc_time: float, reach_time: float,
                 circle_ramp: float) -> None:
        from franka_vs_gym.control.cartesian import CartesianComputedTorque
        from franka_vs_gym.control.impedance import GravityCompensation

        self.robot, self.dt = left, dt
        self.gc_time, self.reach_time, self.circle_ramp = gc_time, reach_time, circle_ramp
        self.gc = GravityCompensation(ctrl_model, internal=left.model, kd=2.0)
        self.cct = CartesianComputedTorque(ctrl_model, kp=[400.0, 400.0, 400.0, 300.0, 300.0, 300.0],
                                           internal=left.model)
        self.wMf = left.get_wMf()
        self.fMe_start = np.linalg.inv(self.wMf) @ circle_start_pose()
        self.circle_start_t = gc_time + reach_time
        self.u_axis = np.array([0.0, 0.0, 1.0])  # the circle starts at its top: centre = start - r u
        self.v_axis = np.array([1.0, 0.0, 0.0])
        self.fMe_reach0 = left.get_fMe()
        self.wMe0 = self.wMf @ self.fMe_reach0
        self.gc_drift = 0.0

    def command(self, k: int, t: float) -> tuple[int, np.ndarray]:
        """Send this tick's torque; returns (phase, reference position of the end effector in the world (3,))."""
        from franka_vs_gym.control.cartesian import circle_reference
        from franka_vs_gym.sim.robot import JOINT_STATE

        left = self.robot
        ql, dql = left.get_position(), left.get_velocity()
        if t < self.gc_time:
            phase = 0
            tau = self.gc(ql, dql)
            ref_w = self.wMe0[:3, 3]
            self.gc_drift = max(self.gc_drift, float(np.linalg.norm(left.get_fMe()[:3, 3] - self.fMe_reach0[:3, 3])))
        elif t < self.circle_start_t:
            phase = 1
            if k == int(round(self.gc_time / self.dt)):
                self.fMe_reach0 = left.get_fMe()
            fMe_reach0, fMe_start = self.fMe_reach0, self.fMe_start
            s, ds, dds = minimum_jerk(t - self.gc_time, self.reach_time)
            dp = fMe_start[:3, 3] - fMe_reach0[:3, 3]
            rot = _rotvec(fMe_start[:3, :3] @ fMe_reach0[:3, :3].T)
            Md = homogeneous(_exp(s * rot) @ fMe_reach0[:3, :3], fMe_reach0[:3, 3] + s * dp)
            vd = np.concatenate([ds * dp, ds * rot])
            ad = np.concatenate([dds * dp, dds * rot])
            tau = self.cct(t, ql, dql, Md, vd, ad)
            ref_w = (self.wMf @ Md)[:3, 3]
        else:
            phase = 2
            p, dp_, ddp = circle_reference(t - self.circle_start_t, self.fMe_start[:3, 3], CIRCLE_RADIUS,
                                           CIRCLE_FREQUENCY, axis_u=self.u_axis, axis_v=self.v_axis,
                                           ramp=self.circle_ramp)
            Md = homogeneous(self.fMe_start[:3, :3], p)
            tau = self.cct(t, ql, dql, Md, np.r_[dp_, 0.0, 0.0, 0.0], np.r_[ddp, 0.0, 0.0, 0.0])
            ref_w = (self.wMf @ Md)[:3, 3]
        left.set_force_torque(JOINT_STATE, tau)
        return phase, ref_w


class _RightArm:
    """The right arm's loop: PBVS on the tag at the camera rate (with the tag's estimated own velocity as
    feed-forward), smoothed at 1 kHz, plus the visual admittance ``admittance * F/T force``."""

    def __init__(self, right, meas: _TagMeasurement, dt: float, cam_every: int, pbvs_gain: float,
                 admittance: float, force_filter: float, command_filter: float, feedforward: bool) -> None:
        self.robot, self.meas, self.cam_every = right, meas, cam_every
        self.pbvs_gain, self.admittance, self.feedforward = pbvs_gain, admittance, feedforward
        self.eRc = right.get_eMc()[:3, :3]
        self.v_pbvs = np.zeros(6)
        self.target_vel_f = np.zeros(3)  # estimated velocity of the tag in the right base frame, m/s
        self.last_f_to: np.ndarray | None = None
        self.last_cam_t = 0.0
        self.visible = False
        self.wrist_img: np.ndarray | None = None
        self.wf = np.zeros(3)  # F/T force in c, low-pass filtered with time constant force_filter
        self.alpha = 1.0 if force_filter == 0 else 1.0 - math.exp(-dt / force_filter)
        self.beta = 1.0 if command_filter == 0 else 1.0 - math.exp(-dt / command_filter)
        self.v_smooth = np.zeros(6)  # the PBVS twist, low-pass filtered at 1 kHz (no steps at each camera frame)
        self.f_e = np.zeros(3)

    def _camera_frame(self, t: float) -> None:
        cMo, img = self.meas.measure()
        if img is not None:
            self.wrist_img = img
        self.visible = cMo is not None
        if cMo is None:
            self.v_pbvs = np.zeros(6)
            self.target_vel_f = np.zeros(3)
            self.last_f_to = None
            return
        fMc = self.robot.get_fMc()
        f_to = fMc[:3, :3] @ cMo[:3, 3] + fMc[:3, 3]  # the tag's origin in the right base frame
        if self.feedforward and self.last_f_to is not None and t > self.last_cam_t:
            # the tag's own velocity, from two poses in the (fixed) base frame: robust to how the camera moved in
            # between (contact bounces included)
            self.target_vel_f = 0.5 * self.target_vel_f + 0.5 * (f_to - self.last_f_to) / (t - self.last_cam_t)
        target_motion = fMc[:3, :3].T @ self.target_vel_f
        self.last_f_to = f_to
        self.last_cam_t = t
        self.v_pbvs = pbvs_twist(cMo, cdMo, self.pbvs_gain, target_motion)

    def command(self, k: int, t: float) -> None:
        """Send this tick's camera twist (PBVS + admittance, translation capped at 0.5 m/s)."""
        from franka_vs_gym.sim.robot import CAMERA_FRAME

        if k % self.cam_every == 0:
            self._camera_frame(t)
        self.f_e = self.robot.get_ft_wrench()[:3]
        self.wf += self.alpha * (self.eRc.T @ self.f_e - self.wf)
        self.v_smooth += self.beta * (self.v_pbvs - self.v_smooth)
        v_cmd = self.v_smooth.copy()
        v_cmd[:3] += self.admittance * self.wf
        nv = np.linalg.norm(v_cmd[:3])
        if nv > 0.5:
            v_cmd[:3] *= 0.5 / nv
        self.robot.set_velocity(CAMERA_FRAME, v_cmd)


class _DualArmLog:
    """The logged time series and the obstacle contacts (which bodies touched it, the right arm's contact force)."""

    KEYS = ("time", "phase", "left_ee", "left_ref", "right_ee", "tag", "pbvs_error", "contact_force", "ft_force",
            "visible")

    def __init__(self, world: SimWorld, obstacle: bool) -> None:
        self.world = world
        m = world.model
        self.obstacle_geom = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "obstacle") if obstacle else -1
        self.body_names = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or "" for b in range(m.nbody)]
        self.right_bodies = {b for b, name in enumerate(self.body_names) if name.startswith("right_")}
        self.touched: set[str] = set()  # bodies that touched the obstacle
        self.rows: dict[str, list] = {k: [] for k in self.KEYS}
        self._cfr = np.zeros(6)

    def _contact_force(self) -> float:
        m, d, og = self.world.model, self.world.data, self.obstacle_geom
        force = 0.0
        if og >= 0:
            for i in range(d.ncon):
                c = d.contact[i]
                if og in (c.geom1, c.geom2):
                    other = c.geom2 if c.geom1 == og else c.geom1
                    self.touched.add(self.body_names[int(m.geom_bodyid[other])])
                    if int(m.geom_bodyid[other]) in self.right_bodies:
                        mujoco.mj_contactForce(m, d, i, self._cfr)
                        force += float(np.linalg.norm(self._cfr[:3]))
        return force

    def record(self, t: float, phase: int, left: _LeftArm, ref_w: np.ndarray, right: _RightArm) -> None:
        rows = self.rows
        force = self._contact_force()
        r = right.robot
        wMe_r = r.get_wMf() @ r.get_fMe()
        rows["time"].append(t)
        rows["phase"].append(phase)
        rows["left_ee"].append((left.wMf @ left.robot.get_fMe())[:3, 3])
        rows["left_ref"].append(ref_w)
        rows["right_ee"].append(wMe_r[:3, 3])
        rows["tag"].append(self.world.data.xpos[right.meas.tag_body].copy())
        true = right.meas.true_cMo()
        rows["pbvs_error"].append(np.concatenate([true[:3, 3] - cdMo[:3, 3], _rotvec(cdMo[:3, :3] @ true[:3, :3].T)]))
        rows["contact_force"].append(force)
        rows["ft_force"].append(right.f_e.copy())
        rows["visible"].append(right.visible)


def _video_writer(video: str | Path | None, fps: int):
    if not video:
        return None
    import imageio.v2 as imageio

    vp = Path(video)
    if vp.exists():
        raise FileExistsError(f"{vp} exists; not overwriting it")
    return imageio.get_writer(str(vp), fps=fps, codec="libx264", quality=7, macro_block_size=8)


def run_dual_arm(duration: float = 20.0, *, camera_rate: float = 30.0, vision: str = "ideal", obstacle: bool = True,
                 gc_time: float = 2.0, reach_time: float = 2.0, circle_ramp: float = 1.0, pbvs_gain: float = 6.0,
                 admittance: float = 0.004, force_filter: float = 0.02, command_filter: float = 0.015,
                 feedforward: bool = True, pixel_noise: float = 0.0, seed: int = 0, progress: bool = True,
                 video: str | Path | None = None, video_fps: int = 25, video_size: tuple[int, int] = (480, 360),
                 log_rate: float = 200.0) -> DualArmResult:
    """Run the dual-arm experiment; returns its time series.

    duration (s) > 0; camera_rate (Hz) of the PBVS loop; vision "ideal" | "detect"; pbvs_gain lambda (1/s);
    admittance A (m/s per N) of the vision-force law; force_filter (s) time constant of the F/T low-pass;
    command_filter (s) time constant smoothing the PBVS twist between camera frames; feedforward: add the tag's
    estimated own velocity to PBVS; pixel_noise (px, std) on the ideal corners (then the pose is estimated by PnP
    from them), drawn from a generator seeded by ``seed``; video an .mp4 path (overview + wrist view) or None;
    log_rate (Hz) of the returned time series (the control runs at 1 kHz).
    """
    from tqdm import tqdm

    from franka_vs_gym.sim.robot import FORCE_TORQUE, VELOCITY

    _check_dual_arm_settings(duration, camera_rate, pbvs_gain, log_rate, vision, gc_time=gc_time,
                             reach_time=reach_time, circle_ramp=circle_ramp, admittance=admittance,
                             force_filter=force_filter, command_filter=command_filter)
    world, left_sim, right_sim, ctrl_model = build_world(obstacle)
    dt = world.dt
    n = int(round(duration / dt))
    log_every = max(1, int(round(1.0 / (log_rate * dt))))
    frame_every = max(1, int(round(1.0 / (video_fps * dt))))
    meas = _TagMeasurement(world, right_sim, vision, period=1.0 / camera_rate, noise_px=pixel_noise, seed=seed)
    left = _LeftArm(left_sim, ctrl_model, dt, gc_time, reach_time, circle_ramp)
    right = _RightArm(right_sim, meas, dt, max(1, int(round(1.0 / (camera_rate * dt)))), pbvs_gain, admittance,
                      force_filter, command_filter, feedforward)
    left_sim.set_robot_state(FORCE_TORQUE)
    right_sim.set_robot_state(VELOCITY)
    log = _DualArmLog(world, obstacle)
    ctrl_time = 0.0  # wall-clock seconds in the two controllers and the tag measurement
    frames = 0
    writer = _video_writer(video, video_fps)
    try:
        for k in tqdm(range(n), desc="dual-arm", unit="tick", file=sys.stderr, disable=not progress,
                      mininterval=0.5, unit_scale=True):
            t = k * dt
            c0 = time.perf_counter()
            phase, ref_w = left.command(k, t)
            right.command(k, t)
            ctrl_time += time.perf_counter() - c0
            if writer is not None and k % frame_every == 0:
                over = world.render("franko_view", *video_size)
                if vision != "detect" or right.wrist_img is None:
                    right.wrist_img = world.render(right_sim.camera_name(), *video_size)
                w_img = right.wrist_img
                w_img = w_img if w_img.shape[:2] == over.shape[:2] else _resize(w_img, over.shape)
                writer.append_data(np.concatenate([over, w_img], axis=1))
                frames += 1
            world.step()
            if k % log_every == 0:
                log.record(t + dt, phase, left, ref_w, right)
    finally:
        if writer is not None:
            writer.close()
        world.close()
    arr = {k: np.asarray(v) for k, v in log.rows.items()}
    settings = {"camera_rate_hz": camera_rate, "vision": vision, "obstacle": obstacle, "gc_time_s": gc_time,
                "reach_time_s": reach_time, "circle_start_s": left.circle_start_t, "circle_ramp_s": circle_ramp,
                "circle_radius_m": CIRCLE_RADIUS, "circle_frequency_hz": CIRCLE_FREQUENCY, "pbvs_gain": pbvs_gain,
                "pbvs_depth_m": PBVS_DEPTH, "admittance_m_per_s_per_n": admittance,
                "controllers_wall_time_us_per_tick": 1e6 * ctrl_time / n,
                "bodies_touching_obstacle": sorted(log.touched), "force_filter_s": force_filter,
                "command_filter_s": command_filter, "seed": seed,
                "pixel_noise_px": pixel_noise,
                "tag_holder_kg": TAG_HOLDER.mass, "control_rate_hz": 1.0 / dt, "log_rate_hz": log_rate,
                "obstacle_top_z_m": float(OBSTACLE_POS[2] + OBSTACLE_HALF[2]) if obstacle else None}
    return DualArmResult(arr["time"], arr["phase"].astype(int), arr["left_ee"], arr["left_ref"], arr["right_ee"],
                         arr["tag"], arr["pbvs_error"], arr["contact_force"], arr["ft_force"],
                         arr["visible"].astype(bool), settings, left.gc_drift, frames)


def _resize(img: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    import cv2

    return cv2.resize(img, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def plot_dual_arm(result: DualArmResult, folder: Path) -> list[Path]:
    """paths.png, contact_force.png and pbvs_error.png in folder."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    r, out = result, []
    circ = r.phase == 2
    title = "End-effector paths in the x-z plane (circle phase)"
    if not circ.any():  # a short run that ended before the circle: show what there is
        circ = np.ones(len(r.time), dtype=bool)
        title = "End-effector paths in the x-z plane (whole run, the circle phase was not reached)"
    fig, ax = plt.subplots(figsize=(7, 6))
    ax.plot(r.left_ee[circ, 0], r.left_ee[circ, 2], "C0", lw=1.2, label="left end effector (circle)")
    ax.plot(r.left_ref[circ, 0], r.left_ref[circ, 2], "k:", lw=1.0, label="left reference")
    ax.plot(r.right_ee[circ, 0], r.right_ee[circ, 2], "C3", lw=1.2, label="right end effector (PBVS + contact)")
    top = r.settings.get("obstacle_top_z_m")
    if top is not None:
        ax.axhline(top, color="C1", ls="--", lw=1.0, label="obstacle top (touched by the hand's lower edge)")
    ax.set_xlabel("x [m] (world)")
    ax.set_ylabel("z [m] (world)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    out.append(folder / "paths.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(9, 4))
    ax.plot(r.time, r.contact_force, "C3", lw=1.0, label="contact force obstacle-gripper (MuJoCo)")
    ax.plot(r.time, np.linalg.norm(r.ft_force, axis=1), "C0", lw=0.8, alpha=0.8, label="|f| wrist F/T sensor")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("force [N]")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    out.append(folder / "contact_force.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i, lab in enumerate("xyz"):
        axes[0].plot(r.time, 1e3 * r.pbvs_error[:, i], lw=1.0, label=f"t_{lab} - t*_{lab}")
        axes[1].plot(r.time, np.degrees(r.pbvs_error[:, 3 + i]), lw=1.0, label=f"theta u_{lab}")
    axes[0].set_ylabel("translation error [mm]")
    axes[1].set_ylabel("rotation error [deg]")
    axes[1].set_xlabel("time [s]")
    for a in axes:
        a.grid(alpha=0.3)
        a.legend(fontsize=8, ncol=3)
    fig.tight_layout()
    out.append(folder / "pbvs_error.png")
    fig.savefig(out[-1], dpi=110)
    plt.close(fig)
    return out


def write_dual_arm(result: DualArmResult, folder: str | Path) -> dict[str, Path]:
    """Write the plots, metrics.json and the time series (timeseries.npz) into an existing folder."""
    folder = Path(folder)
    written = {p.stem: p for p in plot_dual_arm(result, folder)}
    for name in ("metrics.json", "timeseries.npz"):
        if (folder / name).exists():
            raise FileExistsError(f"{folder / name} exists; not overwriting it")
    (folder / "metrics.json").write_text(json.dumps(result.metrics(), indent=2))
    written["metrics"] = folder / "metrics.json"
    np.savez_compressed(folder / "timeseries.npz", time=result.time, phase=result.phase, left_ee=result.left_ee,
                        left_ref=result.left_ref, right_ee=result.right_ee, tag=result.tag,
                        pbvs_error=result.pbvs_error, contact_force=result.contact_force, ft_force=result.ft_force,
                        visible=result.visible)
    written["timeseries"] = folder / "timeseries.npz"
    return written


__all__ = ["DualArmResult", "build_world", "cdMo", "circle_start_pose", "initial_configurations", "minimum_jerk",
           "pbvs_twist", "plot_dual_arm", "run_dual_arm", "write_dual_arm"]
