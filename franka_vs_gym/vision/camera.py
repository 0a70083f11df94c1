"""Pinhole camera model matching MuJoCo's offscreen rendering, and the wrist camera with its own frame rate.

Conventions (as ViSP and OpenCV): camera frame c with z forward (optical axis), x right, y down. Pixel (u, v) has
u along image columns and v along rows, integer values at pixel centres, (0, 0) the centre of the top-left pixel.
Normalized coordinates x = X/Z, y = Y/Z; u = cx + fx x, v = cy + fy y.

MuJoCo renders a symmetric frustum whose vertical field of view is the camera's ``fovy``, so a MuJoCo camera has
square pixels, fx = fy = (height / 2) / tan(fovy / 2), and its principal point at the image centre,
cx = width / 2 - 0.5, cy = height / 2 - 0.5 (pixel-centre convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import mujoco
import numpy as np


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics: fx, fy, cx, cy in pixels; width, height of the image in pixels."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be > 0 px, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_fovy(cls, width: int, height: int, fovy_deg: float) -> CameraIntrinsics:
        """Intrinsics of a MuJoCo camera of vertical field of view ``fovy_deg`` rendering width x height."""
        if not 0 < fovy_deg < 180:
            raise ValueError(f"fovy must be in (0, 180) degrees, got {fovy_deg}")
        f = (height / 2) / math.tan(math.radians(fovy_deg) / 2)
        return cls(f, f, width / 2 - 0.5, height / 2 - 0.5, int(width), int(height))

    @classmethod
    def default(cls, width: int = 320, height: int = 240) -> CameraIntrinsics:
        """The default wrist camera: 60 deg vertical field of view (close to a RealSense D435's colour stream)."""
        return cls.from_fovy(width, height, 60.0)

    @property
    def fovy_deg(self) -> float:
        return math.degrees(2 * math.atan((self.height / 2) / self.fy))

    @cached_property
    def pixel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(f = (fx, fy), c = (cx, cy), the largest pixel coordinates inside the image (width - 0.5, height - 0.5)),
        (2,) each in pixels, read-only: u = fx x + cx, v = fy y + cy of normalized coordinates (x, y)."""
        out = (np.array([self.fx, self.fy]), np.array([self.cx, self.cy]),
               np.array([self.width - 0.5, self.height - 0.5]))
        for a in out:
            a.flags.writeable = False
        return out

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> CameraIntrinsics:
        """The same field of view rendered at another resolution."""
        return CameraIntrinsics.from_fovy(width, height, self.fovy_deg)

    def check_mujoco_compatible(self) -> None:
        """MuJoCo cameras have square pixels and a centred principal point; raise if these intrinsics do not."""
        if abs(self.fx - self.fy) > 1e-9 * self.fx:
            raise ValueError(f"MuJoCo renders square pixels: fx must equal fy (got {self.fx}, {self.fy})")
        if abs(self.cx - (self.width / 2 - 0.5)) > 1e-9 or abs(self.cy - (self.height / 2 - 0.5)) > 1e-9:
            raise ValueError("MuJoCo renders a centred principal point: cx = width/2 - 0.5, cy = height/2 - 0.5")

    # ------------------------------------------------------------------ projection
    def project(self, cP: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) of 3D points (n, 3) given in the camera frame (Z must be > 0)."""
        P = np.atleast_2d(np.asarray(cP, dtype=np.float64))
        Z = P[:, 2]
        if (Z <= 0).any():
            raise ValueError("cannot project points at or behind the camera (Z <= 0)")
        return np.column_stack([self.cx + self.fx * P[:, 0] / Z, self.cy + self.fy * P[:, 1] / Z])

    def to_normalized(self, uv: np.ndarray) -> np.ndarray:
        """Normalized coordinates (n, 2) of pixels (n, 2)."""
        uv = np.atleast_2d(np.asarray(uv, dtype=np.float64))
        return np.column_stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy])

    def to_pixels(self, xy: np.ndarray) -> np.ndarray:
        """Pixels (n, 2) of normalized coordinates (n, 2)."""
        xy = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        return np.column_stack([self.cx + self.fx * xy[:, 0], self.cy + self.fy * xy[:, 1]])

    def in_image(self, uv: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Whether each pixel (n, 2) lies inside the image, ``margin`` pixels from its border."""
        uv = np.atleast_2d(uv)
        return ((uv[:, 0] >= -0.5 + margin) & (uv[:, 0] <= self.width - 0.5 - margin)
                & (uv[:, 1] >= -0.5 + margin) & (uv[:, 1] <= self.height - 0.5 - margin))


def set_mujoco_camera(model: mujoco.MjModel, camera: int | str, intrinsics: CameraIntrinsics) -> None:
    """Give a MuJoCo camera the field of view of ``intrinsics`` (which must be MuJoCo-compatible)."""
    intrinsics.check_mujoco_compatible()
    cam = camera if isinstance(camera, int) else mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
    if cam < 0:
        raise ValueError(f"no camera {camera!r} in the model")
    model.cam_fovy[cam] = intrinsics.fovy_deg
    for w, h in ((model.vis.global_.offwidth, intrinsics.width), (model.vis.global_.offheight, intrinsics.height)):
        if h > w:
            raise ValueError(f"image {intrinsics.width}x{intrinsics.height} exceeds the model's offscreen buffer "
                             f"{model.vis.global_.offwidth}x{model.vis.global_.offheight}")


class WristCamera:
    """The robot's wrist camera: renders the simulated image and holds it between frames.

    The camera runs at its own period (e.g. 20 ms = 50 Hz) independently of the control loop (e.g. 1 ms): between
    two frames, :meth:`image` returns the last frame, as a real camera does. Frames are taken at simulated times
    k * period.

    Parameters
    ----------
    sim : FrankaSim
        The robot carrying the camera (its mount is ``sim.get_eMc()``).
    intrinsics : CameraIntrinsics
        Image size and focal lengths (MuJoCo-compatible: square pixels, centred principal point).
    period : float
        Time between frames, s.
    camera : str or None
        The MuJoCo camera rendered (default the robot's wrist camera; e.g. a camera fixed in the world).
    """

    def __init__(self, sim, intrinsics: CameraIntrinsics | None = None, period: float = 0.02,
                 camera: str | None = None) -> None:
        if not (period > 0 and math.isfinite(period)):
            raise ValueError(f"camera period must be > 0 s, got {period}")
        self.sim = sim
        self.intrinsics = intrinsics or CameraIntrinsics.default()
        self.period = float(period)
        self.name = sim.camera_name() if camera is None else camera
        set_mujoco_camera(sim.world.model, self.name, self.intrinsics)
        self._cam_id = mujoco.mj_name2id(sim.world.model, mujoco.mjtObj.mjOBJ_CAMERA, self.name)
        sim.world.renderer(self.intrinsics.width, self.intrinsics.height)  # made now: fails here if it cannot render
        self._last_t = -math.inf
        self._image: np.ndarray | None = None
        self.frame_count = 0

    def render(self) -> np.ndarray:
        """Render the camera's view now, (height, width, 3) uint8 (a new array)."""
        return self.sim.world.render(self._cam_id, self.intrinsics.width, self.intrinsics.height)

    def new_frame_due(self) -> bool:
        return self.sim.time >= self._last_t + self.period - 1e-9

    def image(self) -> tuple[np.ndarray, bool]:
        """(image, is_new): a fresh frame when one is due at the current simulated time, else the held one."""
        if self._image is None or self.new_frame_due():
            self._image = self.render()
            t = self.sim.time
            self._last_t = math.floor(t / self.period + 1e-9) * self.period
            self.frame_count += 1
            return self._image, True
        return self._image, False
