"""FrankaIBVSEyeToHand-v0 and FrankaPBVSEyeToHand-v0: a camera fixed in the world servoes the AprilTag the hand
carries.

The eye-to-hand counterpart of FrankaIBVS-v0 / FrankaPBVS-v0: the same observation contract, rewards, success and
failure conditions (the task classes' own), with the geometry turned round. The camera c stands on a tripod in front
of the robot; the tag o is on a plate fixed to the front face of the Franka Hand (``eMo``, in the end-effector
frame e). The goal is the tag at ``desired_distance`` in front of the camera, facing it (cdMo), with the arm near its
neutral posture.
"""
# ruff: noqa: E501  (the docstring tables are wider than the code line limit, as in Gymnasium's MuJoCo envs)

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from franka_vs_gym.assets.mjcf import CameraSpec, TagSpec, mat2quat
from franka_vs_gym.envs.base import _nonneg, _positive
from franka_vs_gym.envs.ibvs import FrankaIBVSEnv
from franka_vs_gym.envs.kernels import camera_geometry, pose_records
from franka_vs_gym.envs.pbvs import FrankaPBVSEnv
from franka_vs_gym.envs.visual import VisualServoEnv
from franka_vs_gym.model.config import resolve_config
from franka_vs_gym.model.franka_model import FrankaModel
from franka_vs_gym.model.geometry import (
    CAMERA_VISP_TO_MUJOCO,
    desired_tag_pose,
    homogeneous,
    inverse_pose,
    pose_vector,
    rot_z,
)
from franka_vs_gym.sim import plant
from franka_vs_gym.vision.tags import tag_corners

#: The tag's pose in the end-effector frame e of the Franka Hand: on a plate on the hand's front face (+x_e, 4.5 cm
#: from the hand's axis, 7.5 cm above the fingertips' centre e), facing forward (tag z = x_e), upright when the
#: hand points down (tag y = -z_e, tag x = -y_e), so that the camera stands upright at the goal.
DEFAULT_eMo = homogeneous(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), (0.045, 0.0, -0.075))
CAMERA_NAME = "eye_to_hand_camera"


class EyeToHandEnv(VisualServoEnv):
    """The eye-to-hand scene (see the module docstring and :class:`FrankaIBVSEyeToHandEnv` for the tables)."""

    supported_action_types = ("joint_velocity", "torque")

    def __init__(self, *, camera_shift: float = 0.05, camera_yaw: float = 0.3, eMo: Any = None,
                 desired_distance: float = 0.35, start_distance_range: Any = (0.40, 0.55),
                 start_offset: float = 0.05, **kwargs: Any) -> None:
        given = [k for k in ("tag_x_range", "tag_y_range", "tag_yaw_range") if k in kwargs]
        if given:
            raise ValueError(f"{', '.join(given)}: the eye-to-hand tag is carried by the hand; the episode draws the "
                             "camera's placement instead (camera_shift, camera_yaw)")
        self.camera_shift = _nonneg(camera_shift, "camera_shift")
        self.camera_yaw = _nonneg(camera_yaw, "camera_yaw")
        eMo = DEFAULT_eMo if eMo is None else np.asarray(eMo, dtype=np.float64)
        if eMo.shape != (4, 4) or not np.isfinite(eMo).all() or \
                not np.allclose(eMo[:3, :3] @ eMo[:3, :3].T, np.eye(3), atol=1e-9):
            raise ValueError("eMo must be a 4x4 homogeneous transform with a rotation matrix")
        self.eMo = eMo.copy()
        self.oMe = inverse_pose(self.eMo)
        # the tag is a child of the hand body, whose frame is the flange's: flMo = flMe eMo; the camera starts at its
        # nominal placement (the goal where the neutral posture holds the tag; the robot's base is the world frame)
        cfg = resolve_config(kwargs.get("model"), kwargs.get("robot"))
        self._flMe = cfg.tool.flMe
        self._fMc_nominal = (FrankaModel(cfg).fMe(cfg.robot.neutral()) @ self.eMo
                             @ inverse_pose(desired_tag_pose(_positive(desired_distance, "desired_distance"))))
        super().__init__(desired_distance=desired_distance, start_distance_range=start_distance_range,
                         start_offset=start_offset, **kwargs)
        self._cam_id = self._m.camera(CAMERA_NAME).id
        self._q_nominal = self.config.robot.neutral()
        # the goal of the nominal camera placement: the tag where the neutral posture holds it
        self._fMo_nominal = self.sim.model.fMe(self._q_nominal) @ self.eMo
        self._set_camera(self._fMc_nominal)
        self._truth_scratch = np.zeros((1, self._truth_rec.size))

    # ------------------------------------------------------------------ scene
    def _scene(self, tag: TagSpec, kwargs: dict[str, Any]) -> dict[str, Any]:
        flMo = self._flMe @ self.eMo
        held = TagSpec(tag_id=tag.tag_id, size=tag.size, pos=tuple(flMo[:3, 3]), quat=tuple(mat2quat(flMo[:3, :3])),
                       parent="r0_hand", name="tag")
        return {"camera": False, "tags": [held], "cameras": [CameraSpec.from_visp(CAMERA_NAME, self._fMc_nominal)]}

    def _camera_name(self) -> str:
        return CAMERA_NAME

    def _set_camera(self, fMc: np.ndarray) -> None:
        """Place the fixed camera (ViSP frame c) at fMc in the robot base frame."""
        self.fMc = np.array(fMc, dtype=np.float64)
        self.cMf = inverse_pose(self.fMc)
        self._plan.fMo[:] = self.cMf  # the static pose of the eye-to-hand truth kernel (see _camera_geometry)
        self._truth_k = -1
        self._camera_pose = pose_vector(self.fMc)
        wMc = self.sim.get_wMf() @ self.fMc
        self._m.cam_pos[self._cam_id] = wMc[:3, 3]
        self._m.cam_quat[self._cam_id] = mat2quat(wMc[:3, :3] @ CAMERA_VISP_TO_MUJOCO)

    def _make_observation_space(self) -> spaces.Dict:
        sp = dict(super()._make_observation_space().spaces)
        f32 = np.float32
        sp["camera_pose"] = spaces.Box(np.array([-5, -5, -5, -4, -4, -4], f32), np.array([5, 5, 5, 4, 4, 4], f32),
                                       dtype=f32)
        return spaces.Dict(sp)

    # ------------------------------------------------------------------ geometry
    def get_cMe(self, q: Any = None) -> np.ndarray:
        """Pose of the end effector in the fixed camera's frame (4, 4), now or at joint position q."""
        return self.cMf @ self.sim.get_fMe(q)

    #: the calibrated camera placement, written once per episode
    _static_keys = ("camera_pose",)

    def _camera_geometry(self) -> np.ndarray | None:
        """The compiled truth kernel's eye-to-hand geometry block: the hand's chain carrying the tag (eMo); the step
        plan's static pose is the fixed camera's cMf (written by _set_camera), so the kernel gives cMo = cMf fMe(q)
        eMo (franka_vs_gym/sim/_task.c)."""
        return camera_geometry(self.sim.model, self.eMo, tag_corners(self.tag_size), self.intrinsics,
                               self.features_desired, eye_to_hand=True)

    def _truth_now(self) -> np.ndarray:
        """The truth record of the tag seen by the fixed camera: cMo = cMf fMe(q) eMo, by the compiled truth kernel
        (the robot's kinematic chain as the eye-in-hand tasks') or, without it, with pinocchio's kinematics and
        numpy (the same formulas)."""
        if self._truth_k != self._k:
            plan = self._plan
            plan.refresh(self)
            q = np.ascontiguousarray(self.sim.joint_views()[0])
            if plan.geo_or_none is not None and plant.tag_truth is not None:
                plant.tag_truth(plan.geo, q, plan.fMo, plan.truth)
            else:
                cMo = self.cMf @ self.sim.model.fMe(q) @ self.eMo
                pose_records(cMo[None], self._truth_scratch, tag_size=self.tag_size, intrinsics=self.intrinsics,
                             features_desired=self.features_desired)
                self._truth_rec[:] = self._truth_scratch[0]
            self._truth_k = self._k
        return self._truth_rec

    # ------------------------------------------------------------------ episode
    def _reset_task(self, options: dict[str, Any]) -> np.ndarray:
        rng = self.np_random
        shift = rng.uniform(-self.camera_shift, self.camera_shift, 3) if self.camera_shift else np.zeros(3)
        yaw = float(rng.uniform(-self.camera_yaw, self.camera_yaw)) if self.camera_yaw else 0.0
        fMo_goal = self._fMo_nominal.copy()
        fMo_goal[:3, :3] = rot_z(yaw) @ fMo_goal[:3, :3]
        fMo_goal[:3, 3] += shift
        fMc = fMo_goal @ inverse_pose(self.cdMo)
        self._set_camera(fMc)
        model = self.sim.model
        try:
            q_goal = model.inverse_kinematics(fMo_goal @ self.oMe, self._q_nominal, restarts=0, tol=1e-6)
        except ValueError:
            q_goal = self._q_nominal
        self._q_goal = q_goal
        if "q0" in options:
            return np.asarray(options["q0"], dtype=np.float64)
        margin = 0.1
        for _ in range(50):
            c0Mo = self._sample_start()
            if c0Mo is None:
                continue
            try:
                q0 = model.inverse_kinematics(fMc @ c0Mo @ self.oMe, q_goal, restarts=0, tol=1e-6)
            except ValueError:
                continue
            if (q0 > self.q_min + margin).all() and (q0 < self.q_max - margin).all():
                return q0
        raise RuntimeError("could not draw a start pose with the tag in view and the arm within its limits after "
                           "50 tries: check the camera and start ranges")

    def _after_reset(self) -> None:
        self._pack.write("camera_pose", self._camera_pose)
        super()._after_reset()

    def _reset_info(self) -> dict[str, Any]:
        return {**super()._reset_info(), "fMc": self.fMc.copy()}


_TABLES = """
    ## Scene
    A camera (``detection_width`` x ``detection_height``, 60 degree vertical field of view, ViSP frame c: z forward,
    y down) stands in front of the robot; an AprilTag (36h11, ``tag_size`` = 8 cm) is fixed to the front face of the
    Franka Hand (``eMo``: 4.5 cm in front of the hand's axis, 7.5 cm above the fingertips, facing along x_e). The goal
    cdMo puts the tag ``desired_distance`` (0.35 m) in front of the camera, centred and facing it. Each episode draws
    the camera's placement: the goal moved by up to ``camera_shift`` (5 cm) per axis and turned by up to
    ``camera_yaw`` (0.3 rad) about the vertical, the camera following it (fMc = fMo* cdMo^-1); the start puts the
    tag 0.40 to 0.55 m from the camera (``start_distance_range``), offset sideways by up to ``start_offset``
    (5 cm at the goal distance), rolled and tilted as in FrankaIBVS-v0, whole in the image; joint positions by
    inverse kinematics.

    ## Action space
    ``"joint_velocity"`` (default) or ``"torque"``, as FrankaIBVS-v0 (a camera twist is not an action here: the
    camera does not move).

    ## Observation space
    FrankaIBVS-v0's keys (``features``, ``feature_depth``, ``tag_pose`` = cMo ... measured by the fixed camera at
    ``camera_period``), plus ``camera_pose`` (6,): fMc, the calibrated camera placement in the robot base frame
    (t in m, theta-u in rad), constant during an episode: what an eye-to-hand law needs to map the robot's twist
    into the camera frame (cVf).
"""


class FrankaIBVSEyeToHandEnv(EyeToHandEnv, FrankaIBVSEnv):
    __doc__ = """Bring the image of the tag the hand carries to its goal in a camera fixed in the world (image-based,
    eye-to-hand). Reward, success (``||s - s*|| < success_threshold``), failures and truncation are
    FrankaIBVS-v0's.
    """ + _TABLES


class FrankaPBVSEyeToHandEnv(EyeToHandEnv, FrankaPBVSEnv):
    __doc__ = """Bring the tag the hand carries to the goal pose cdMo in a camera fixed in the world (position-based,
    eye-to-hand). Reward, success (5 mm, 0.02 rad on cdMc = cdMo cMo^-1), failures and truncation are
    FrankaPBVS-v0's.
    """ + _TABLES


__all__ = ["CAMERA_NAME", "DEFAULT_eMo", "EyeToHandEnv", "FrankaIBVSEyeToHandEnv", "FrankaPBVSEyeToHandEnv"]
