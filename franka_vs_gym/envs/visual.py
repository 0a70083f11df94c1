"""Shared part of the visual-servoing tasks: an AprilTag on the table, the wrist camera, the observation contract.

The task classes (``ibvs.py``, ``pbvs.py``, ``visual_torque.py``) only choose the error, reward and defaults. The
camera model, projection, detection and pose estimation are :mod:`franka_vs_gym.vision`'s; this module decides
*when* the camera sees (its own period, independent of the control period) and what the agent observes.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces

from franka_vs_gym.assets.mjcf import TagSpec, mat2quat
from franka_vs_gym.envs.base import FrankaEnv, ObservationPacker, _nonneg, _positive, _range, substeps
from franka_vs_gym.envs.compiled import CompiledStep
from franka_vs_gym.envs.kernels import (
    R_CMO,
    R_DEPTH,
    R_FEATURES,
    R_POSE,
    R_VISIBLE,
    camera_geometry,
    truth_records,
)
from franka_vs_gym.model.description import TAG_SIZE
from franka_vs_gym.model.geometry import desired_tag_pose, homogeneous, inverse_pose, pose_vector, rot_x, rot_y, rot_z
from franka_vs_gym.sim import plant
from franka_vs_gym.sim.reflexes import ControlException
from franka_vs_gym.vision.tags import tag_corners

FEATURE_SOURCES = ("ideal", "detection")



class VisualServoEnv(FrankaEnv):
    """Base of the visual-servoing tasks. See :class:`~franka_vs_gym.envs.ibvs.FrankaIBVSEnv` for the tables."""

    def __init__(self, *, observation_type: str = "features", camera_period: float = 0.05,
                 tag_size: float = TAG_SIZE, tag_id: int = 0, tag_x_range: Any = (0.45, 0.60),
                 tag_y_range: Any = (-0.10, 0.10), tag_yaw_range: Any = (-0.5, 0.5), desired_distance: float = 0.20,
                 start_distance_range: Any = (0.26, 0.40), start_offset: float = 0.05, start_roll: float = 0.5,
                 start_tilt: float = 0.15, feature_noise: float = 0.0, feature_source: str = "ideal",
                 image_width: int = 128, image_height: int = 96, detection_width: int = 320,
                 detection_height: int = 240, terminate_on_tag_lost: bool = True, success_bonus: float = 1.0,
                 **kwargs: Any) -> None:
        self.tag_size = _positive(tag_size, "tag_size")
        if not isinstance(tag_id, (int, np.integer)) or tag_id < 0:
            raise ValueError(f"tag_id must be an integer >= 0, got {tag_id!r}")
        self.tag_id = int(tag_id)
        self.tag_x_range = _range(tag_x_range, "tag_x_range")
        self.tag_y_range = _range(tag_y_range, "tag_y_range")
        self.tag_yaw_range = _range(tag_yaw_range, "tag_yaw_range")
        self.desired_distance = _positive(desired_distance, "desired_distance")
        self.start_distance_range = _range(start_distance_range, "start_distance_range", positive=True)
        self.start_offset = _nonneg(start_offset, "start_offset")
        self.start_roll = _nonneg(start_roll, "start_roll")
        self.start_tilt = _nonneg(start_tilt, "start_tilt")
        self.feature_noise = _nonneg(feature_noise, "feature_noise")
        if feature_source not in FEATURE_SOURCES:
            raise ValueError(f"feature_source must be one of {FEATURE_SOURCES}, got {feature_source!r}")
        self.feature_source = feature_source
        self.image_width, self.image_height = int(image_width), int(image_height)
        self.detection_width, self.detection_height = int(detection_width), int(detection_height)
        for name, v in (("image_width", self.image_width), ("image_height", self.image_height),
                        ("detection_width", self.detection_width), ("detection_height", self.detection_height)):
            if v < 8:
                raise ValueError(f"{name} must be >= 8 pixels, got {v}")
        self.terminate_on_tag_lost = bool(terminate_on_tag_lost)
        self.success_bonus = _nonneg(success_bonus, "success_bonus")
        tag = TagSpec(tag_id=self.tag_id, size=self.tag_size, pos=(0.55, 0.0, 0.0))
        kwargs.update(self._scene(tag, kwargs))
        super().__init__(observation_type=observation_type, **kwargs)
        self.camera_period = _positive(camera_period, "camera_period")
        self.camera_substeps = substeps(self.camera_period, self.physics_step)
        m = self._m
        self._tag_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, tag.name)
        self._cam_name = self._camera_name()
        self._setup_camera()
        self.cdMo = desired_tag_pose(self.desired_distance)
        self.features_desired, self.depth_desired, ok = self._project(self.cdMo)
        if not ok:
            raise ValueError(f"the goal pose does not show the whole tag (tag_size {self.tag_size} m at "
                             f"desired_distance {self.desired_distance} m)")
        self.tag_pose_desired = pose_vector(self.cdMo)
        self._q_goal_guess = self.config.robot.neutral()
        self._k = 0  # physics steps since the episode start
        self.observation_space = self._make_observation_space()
        self._pack = ObservationPacker(self.observation_space)
        # the truth, the held frame and the packer's work vector live in one block shared with the compiled step
        self._plan = StepPlan(self)
        self._truth_k = -1  # the physics step (self._k) the truth record is of; -1: not computed
        self._frame_no = 0  # camera frames taken (the held frame's number)
        self._packed_frame_no = -1  # the frame whose keys the packer's work vector holds
        self._frame_image: np.ndarray | None = None
        self._fMo = self.get_fMo()

    # ------------------------------------------------------------------ scene hooks (the eye-to-hand tasks override)
    def _scene(self, tag: TagSpec, kwargs: dict[str, Any]) -> dict[str, Any]:
        """FrankaEnv's scene arguments: the wrist camera and the tag on the table."""
        return {"camera": True, "tags": [tag]}

    def _camera_name(self) -> str:
        """The MuJoCo camera that sees the tag."""
        return self.sim.camera_name()

    def _camera_geometry(self) -> np.ndarray | None:
        """The compiled truth kernel's geometry block of this scene (:func:`~franka_vs_gym.envs.kernels.
        camera_geometry`: the wrist camera on the robot's chain), made again when the robot's kinematic model or
        camera mount changes (``FrankaSim.kinematics_key``); the step plan's static pose (``_fMo``) goes with it."""
        return camera_geometry(self.sim.model, self.sim.get_eMc(), tag_corners(self.tag_size), self.intrinsics,
                               self.features_desired)

    #: observation keys a task writes into the packer once per episode (the compiled step packs them as they stand)
    _static_keys: tuple[str, ...] = ()

    # ------------------------------------------------------------------ camera (franka_vs_gym.vision)
    def _setup_camera(self) -> None:
        """The camera model, detector and renderers are franka_vs_gym.vision's; features are measured with the
        intrinsics of the detection_width x detection_height camera (feature noise is in its pixels). The
        renderers themselves are made at the first reset (see _make_cameras)."""
        from franka_vs_gym.vision import CameraIntrinsics, set_mujoco_camera

        self.intrinsics = CameraIntrinsics.default(self.detection_width, self.detection_height)
        set_mujoco_camera(self._m, self._cam_name, self.intrinsics)
        self._start_margin_px = 0.1 * min(self.detection_width, self.detection_height)
        self._image_camera = self._detection_camera = self._detector = None
        self._cameras_ready = False

    def _make_cameras(self) -> None:
        """Renderers are created at the first reset, not in the constructor: an OpenGL context must not exist in a
        process that later forks (gymnasium's AsyncVectorEnv builds one env in the parent to read its spaces)."""
        from franka_vs_gym.vision import TagDetector, WristCamera

        if self.observation_type in ("image", "features+image"):
            self._image_camera = WristCamera(self.sim, self.intrinsics.scaled(self.image_width, self.image_height),
                                             self.camera_period, camera=self._cam_name)
        if self.feature_source == "detection" and self.observation_type != "image":
            self._detection_camera = WristCamera(self.sim, self.intrinsics, self.camera_period,
                                                 camera=self._cam_name)
            self._detector = TagDetector()
        self._cameras_ready = True

    def _project(self, cMo: np.ndarray, margin_px: float = 0.0) -> tuple[np.ndarray, np.ndarray, bool]:
        """(features (8,) normalized coordinates, depths (4,) m, whole tag in the image) for a tag pose."""
        from franka_vs_gym.vision import ideal_measurement

        m = ideal_measurement(cMo, self.tag_size, self.intrinsics, margin_px=margin_px)
        return m.corners_xy.ravel(), m.depths, m.visible

    def _measure(self) -> dict[str, np.ndarray]:
        """A camera measurement now: ideal projection + pixel noise, or detection on a rendered image."""
        from franka_vs_gym.vision import detected_measurement, ideal_measurement

        if self.feature_source == "ideal":  # the truth record's values, with noisy corners
            t = self._truth_now()
            m = ideal_measurement(t[R_CMO].reshape(4, 4), self.tag_size, self.intrinsics,
                                  noise_px=self.feature_noise, rng=self.np_random if self.feature_noise else None)
            return {"features": m.corners_xy.ravel(), "feature_depth": t[R_DEPTH], "tag_pose": t[R_POSE],
                    "visible": t[R_VISIBLE:R_VISIBLE + 1]}
        else:
            image = self._detection_camera.render()
            m = detected_measurement(image, self._detector, self.tag_id, self.tag_size, self.intrinsics)
        return {"features": m.corners_xy.ravel(), "feature_depth": m.depths, "tag_pose": pose_vector(m.cMo),
                "visible": np.array([1.0 if m.visible else 0.0])}

    # ------------------------------------------------------------------ spaces
    def _make_observation_space(self) -> spaces.Dict:
        f32 = np.float32
        q_lo, q_hi = self.q_min - 0.2, self.q_max + 0.2
        dq_hi = 2.0 * self.dq_max
        sp: dict[str, spaces.Space] = {
            "q": spaces.Box(q_lo.astype(f32), q_hi.astype(f32), dtype=f32),
            "dq": spaces.Box((-dq_hi).astype(f32), dq_hi.astype(f32), dtype=f32),
        }
        if self.observation_type != "image":
            sp.update({
                "features": spaces.Box(f32(-2.0), f32(2.0), (8,), dtype=f32),
                "features_desired": spaces.Box(f32(-2.0), f32(2.0), (8,), dtype=f32),
                "feature_depth": spaces.Box(f32(0.0), f32(5.0), (4,), dtype=f32),
                "tag_pose": spaces.Box(np.array([-5, -5, -5, -4, -4, -4], f32), np.array([5, 5, 5, 4, 4, 4], f32),
                                       dtype=f32),
                "tag_pose_desired": spaces.Box(np.array([-5, -5, -5, -4, -4, -4], f32),
                                               np.array([5, 5, 5, 4, 4, 4], f32), dtype=f32),
                "visible": spaces.Box(f32(0.0), f32(1.0), (1,), dtype=f32),
            })
        if self.observation_type in ("image", "features+image"):
            sp["image"] = spaces.Box(0, 255, (self.image_height, self.image_width, 3), dtype=np.uint8)
        return spaces.Dict(sp)

    # ------------------------------------------------------------------ geometry
    def get_fMo(self) -> np.ndarray:
        """Pose of the tag in the robot base frame f (4, 4)."""
        d, b = self._d, self._tag_body
        wMo = homogeneous(d.xmat[b].reshape(3, 3), d.xpos[b])
        return inverse_pose(self.sim.get_wMf()) @ wMo

    def get_cMo(self) -> np.ndarray:
        """True pose of the tag in the camera frame c (4, 4)."""
        return self._truth_now()[R_CMO].reshape(4, 4).copy()

    @property
    def _truth_rec(self) -> np.ndarray:
        """The truth record (kernels.REC) of the state ``_truth_k`` says (a view of the step plan)."""
        return self._plan.truth

    @property
    def _frame_rec(self) -> np.ndarray:
        """The held camera frame as a record (features, depths, visible, pose vector; a view of the step plan)."""
        return self._plan.frame

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._pack._work = self._plan.work  # (a copy's packer writes into its own plan's block)

    @property
    def _fMo(self) -> np.ndarray:
        """The tag's pose in the robot base frame (4, 4), static during an episode (a view of the step plan)."""
        return self._plan.fMo

    @_fMo.setter
    def _fMo(self, fMo: np.ndarray) -> None:
        self._plan.fMo[:] = fMo

    def _truth_now(self) -> np.ndarray:
        """The truth record (kernels.REC) of the current state, computed once per physics step: the camera's ground
        truth of the tag (features, depths, visibility, cMo, pose vector, feature error)."""
        if self._truth_k != self._k:
            plan = self._plan
            plan.refresh(self)
            q = np.ascontiguousarray(self.sim.joint_views()[0])
            geo = plan.geo_or_none if plant.tag_truth is not None else None
            truth_records(geo, q[None], plan.fMo.reshape(1, 16), plan.truth[None],
                          fMe=None if geo is not None else self.sim.get_fMe()[None],
                          eMc=self.sim.get_eMc(), tag_size=self.tag_size, intrinsics=self.intrinsics,
                          features_desired=self.features_desired)
            self._truth_k = self._k
        return self._truth_rec

    # ------------------------------------------------------------------ episode
    def _place_tag(self) -> None:
        rng, m = self.np_random, self._m
        x = rng.uniform(*self.tag_x_range) if self.tag_x_range else 0.55
        y = rng.uniform(*self.tag_y_range) if self.tag_y_range else 0.0
        yaw = rng.uniform(*self.tag_yaw_range) if self.tag_yaw_range else 0.0
        m.body_pos[self._tag_body] = (x, y, 0.0)
        m.body_quat[self._tag_body] = mat2quat(rot_z(yaw))
        mujoco.mj_kinematics(m, self._d)

    def _sample_start(self) -> np.ndarray | None:
        """One draw of the start camera pose c0Mo; None if the tag would not be fully visible with a margin."""
        rng = self.np_random
        Z = rng.uniform(*self.start_distance_range)
        tx, ty = rng.uniform(-self.start_offset, self.start_offset, 2) * Z / self.desired_distance
        roll = rng.uniform(-self.start_roll, self.start_roll)
        ax, ay = rng.uniform(-self.start_tilt, self.start_tilt, 2)
        # camera-frame rotation applied to the goal orientation: c0Mo = [R, t] with the tag at depth Z
        R = rot_x(ax) @ rot_y(ay) @ rot_z(roll) @ self.cdMo[:3, :3]
        cMo = homogeneous(R, (tx, ty, Z))
        if not self._project(cMo, self._start_margin_px)[2]:
            return None
        return cMo

    def _reset_task(self, options: dict[str, Any]) -> np.ndarray:
        self._place_tag()
        fMo = self._fMo = self.get_fMo()  # the tag is static during an episode
        eMc = self.sim.get_eMc()
        cMe = inverse_pose(eMc)
        model = self.sim.model
        # goal posture first (a good IK start for the start posture; computed from the neutral pose)
        fMe_goal = fMo @ inverse_pose(self.cdMo) @ cMe
        try:
            q_goal = model.inverse_kinematics(fMe_goal, self._q_goal_guess, restarts=0, tol=1e-6)
        except ValueError:
            q_goal = self._q_goal_guess
        if "q0" in options:
            return np.asarray(options["q0"], dtype=np.float64)
        margin = 0.1
        for _ in range(50):
            c0Mo = self._sample_start()
            if c0Mo is None:
                continue
            fMe0 = fMo @ inverse_pose(c0Mo) @ cMe
            try:
                q0 = model.inverse_kinematics(fMe0, q_goal, restarts=0, tol=1e-6)
            except ValueError:
                continue
            if (q0 > self.q_min + margin).all() and (q0 < self.q_max - margin).all():
                self._q_goal = q_goal
                return q0
        raise RuntimeError("could not draw a start pose with the tag in view and the arm within its limits after "
                           "50 tries: check the tag pose and start ranges")

    def _after_reset(self) -> None:
        if not self._cameras_ready:
            self._make_cameras()
        self._k = 0
        self._truth_k = -1
        self._plan.refresh(self)
        self._capture()

    def _segments(self) -> tuple[tuple[int, bool], ...]:
        n, c = self.n_substeps, self.camera_substeps
        k0, k1 = self._k, self._k + n
        last = (k1 // c) * c  # the last camera frame of this control period
        if last > k0:
            return ((last - k0, True), (k1 - last, False)) if k1 > last else ((last - k0, True),)
        return ((n, False),)

    def _segment_done(self, n: int, capture: bool) -> None:
        self._k += n
        if capture:
            self._capture()

    # ------------------------------------------------------------------ observation
    def _capture(self) -> None:
        """Take a camera frame now: the measured features and/or the image."""
        if self.observation_type != "image":
            f = self._frame_rec
            if self.feature_source == "ideal" and not self.feature_noise:
                f[:] = self._truth_now()
            else:
                m = self._measure()
                f[R_FEATURES], f[R_DEPTH], f[R_POSE], f[R_VISIBLE] = (m["features"], m["feature_depth"],
                                                                      m["tag_pose"], m["visible"][0])
            if not f[R_VISIBLE]:
                f[R_FEATURES] = 0.0
                f[R_DEPTH] = self.depth_desired
                f[R_POSE] = 0.0
        if self._image_camera is not None:
            self._frame_image = self._image_camera.render()
        self._frame_no += 1

    def _write_seen(self, rec: np.ndarray) -> None:
        """The tag keys of the observation from a record whose unseen values are already replaced."""
        w = self._pack.write
        w("features", rec[R_FEATURES])
        w("feature_depth", rec[R_DEPTH])
        w("tag_pose", rec[R_POSE])
        w("visible", rec[R_VISIBLE])
        w("features_desired", self.features_desired)
        w("tag_pose_desired", self.tag_pose_desired)

    def _get_obs(self) -> dict[str, np.ndarray]:
        q, dq = self._noisy_joint_state()
        pack = self._pack
        if self.observation_type == "state":  # the truth now, at the control rate
            t = self._truth_now()
            if t[R_VISIBLE]:
                self._write_seen(t)
            else:
                unseen = t.copy()
                unseen[R_FEATURES], unseen[R_DEPTH], unseen[R_POSE] = 0.0, self.depth_desired, 0.0
                self._write_seen(unseen)
            self._packed_frame_no = -1
        elif self.observation_type != "image" and self._packed_frame_no != self._frame_no:
            # the held frame's keys are written into the packer's buffer once per frame, q and dq at every step
            self._write_seen(self._frame_rec)
            self._packed_frame_no = self._frame_no
        pack.write("q", q)
        pack.write("dq", dq)
        obs = pack.finish()
        if self._frame_image is not None and "image" in self.observation_space.spaces:
            obs["image"] = self._frame_image.copy()  # a held frame must not be shared between observations
        return obs

    def _step_reflex(self, e: ControlException):
        self._truth_k = -1  # the brakes moved the joints within the period: the truth is of the state now
        return super()._step_reflex(e)

    def _reset_info(self) -> dict[str, Any]:
        return {"error": self._task_error()}

    # ------------------------------------------------------------------ task error
    def _task_error(self) -> float:
        raise NotImplementedError

    def _seen(self) -> bool:
        """Whether the whole tag is in the camera's field of view now (ground truth, so that a missed detection or
        a noisy measurement does not end an episode)."""
        return bool(self._truth_now()[R_VISIBLE])


class StepPlan(CompiledStep):
    """A visual environment's compiled step (:mod:`franka_vs_gym.envs.compiled`): the task's block holds the geometry
    of the robot, camera and tag, then come the tag pose fMo and the truth and held-frame records. The
    environment's ``_truth_rec``, ``_frame_rec``, ``_fMo`` and its packer's work vector are views of the block, so the
    Python and the compiled halves of a step read and write the same numbers.

    The compiled step covers joint-torque actions with ideal features (no pixel noise) or state observations, the
    period one physics segment; the general path (``FrankaEnv.step``) takes every other step, with the same bits.
    """

    KEYS = ("q", "dq", "features", "features_desired", "feature_depth", "tag_pose", "tag_pose_desired", "visible")

    def __init__(self, env: VisualServoEnv) -> None:
        super().__init__(env, fast=(plant.visual_post is not None and env.observation_type in ("features", "state")
                                    and env.feature_source == "ideal" and not env.feature_noise))
        self.fMo[:] = np.eye(4)
        self.geo_or_none: np.ndarray | None = None
        self._key: tuple[Any, Any] | None = None
        self.state_flag = 2 if env.observation_type == "state" else 0
        self.depth_d[:], self.pose_d[:] = env.depth_desired, env.tag_pose_desired
        self.cost[0] = float(getattr(env, "torque_cost", 0.0))
        self.camera_substeps = env.camera_substeps
        self.task_end = False  # whether the task ends a compiled step in one call (env._end_compiled; see ibvs.py)
        # the observation's keys and slices when every key is a vector (no reshape: the features observations)
        self.flat_views = None if any(sh is not None for _, _, sh in self.views) else \
            tuple((k, sl) for k, sl, _ in self.views)

    def _bind(self) -> None:
        super()._bind()
        if getattr(self, "geo_or_none", None) is not None:
            self.geo_or_none = self.geo

    def refresh(self, env: VisualServoEnv) -> None:
        """Rebuild the geometry block when the robot's kinematic model (a new tool or payload rebuilds it) or the
        camera mount changed."""
        sim = env.sim
        key = sim.kinematics_key()
        if self._key is not None and key[0] is self._key[0] and key[1] is self._key[1]:
            return
        geo = env._camera_geometry()
        if geo is None:
            self.geo_or_none = None
        else:
            self.geo[:] = geo
            self.geo_or_none = self.geo
        self._key = key
        env._truth_k = -1

    def eligible(self, env: VisualServoEnv) -> bool:
        key, now = self._key, env.sim.kinematics_key()
        if key is None or self.geo_or_none is None or now[0] is not key[0] or now[1] is not key[1]:
            return False
        k0 = env._k
        k1 = k0 + self.n_substeps
        last = (k1 // self.camera_substeps) * self.camera_substeps
        return (last <= k0 or last == k1) and env.sim.runs_inside_mj_step(self.control_state)  # (CompiledStep's)

    def step(self, env: VisualServoEnv, action: Any):
        """One control period in the compiled step; None (nothing done) when the action is not a plain vector inside
        the action space."""
        if not self.command(env, action):
            return None
        n = self.n_substeps
        k1 = env._k + n
        capture = k1 % self.camera_substeps == 0
        flags = (1 if capture else 0) | self.state_flag | (4 if env._packed_frame_no != env._frame_no else 0)
        out = np.empty(self.size, dtype=np.float32)
        code = plant.visual_post(self.P, self.I, self.m_addr, self.d_addr, out, flags)
        if code < 0:  # a diverging state or a reflex: the general path ends the step
            return self.general_end(env, n, capture)
        env._k = env._truth_k = k1
        if capture:
            env._frame_no += 1
        env._packed_frame_no = -1 if self.state_flag else env._frame_no
        if self.task_end and self.flat_views is not None:
            env._pack.last = out
            env._steps += 1
            return env._end_compiled({k: out[sl] for k, sl in self.flat_views}, code)
        return self.finish(env, out, code)

    def post(self, out: np.ndarray) -> int:
        return plant.visual_post(self.P, self.I, self.m_addr, self.d_addr, out, self.state_flag)
