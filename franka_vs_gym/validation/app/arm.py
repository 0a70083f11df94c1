"""The arm in the pose at the page's cursor, drawn by MuJoCo's offscreen renderer from the project's own robot model
(the simulator's scene without camera or table), each link coloured by the residual of the joint that moves it.

Colour: the absolute residual of joint ``j`` at the cursor, in units of its noise floor, from grey-green (within the
noise) through yellow to red (``RED_AT`` noise floors or more). Where no OpenGL context can be made (no EGL or
OSMesa), :meth:`ArmView.image` raises :class:`NoGL` with the reason, and the page says it instead of the picture.
"""

from __future__ import annotations

import base64
import os

import numpy as np

RED_AT = 5.0  # noise floors: the residual drawn fully red


class NoGL(RuntimeError):
    """Offscreen rendering is not available on this machine (the message says why)."""


def residual_colour(level: float) -> tuple[float, float, float]:
    """RGB in [0, 1] for a residual of ``level`` noise floors: green-grey at 1 or less, yellow at (1 + RED_AT) / 2,
    red at RED_AT and above."""
    x = float(np.clip((level - 1.0) / (RED_AT - 1.0), 0.0, 1.0))
    if x < 0.5:
        return (0.45 + 1.0 * x, 0.7, 0.45 - 0.5 * x)
    return (0.95, 0.7 - 1.2 * (x - 0.5), 0.2 - 0.3 * (x - 0.5))


class ArmView:
    """Draws the robot (``robot``: the log's robot description name or object) at joint positions ``q`` (7,) with
    links coloured by ``levels`` (7,) (residual in noise floors). Made lazily; use from one thread."""

    def __init__(self, robot=None, width: int = 420, height: int = 360) -> None:
        self.robot, self.width, self.height = robot, width, height
        self._sim = None
        self._renderer = None
        self._link_of_geom: dict[int, int] = {}
        self.error: str | None = None

    def _make(self) -> None:
        if self._renderer is not None:
            return
        if self.error is not None:
            raise NoGL(self.error)
        try:
            import mujoco

            from franka_vs_gym.sim.rendering import make_renderer
            from franka_vs_gym.sim.robot import FrankaSim

            sim = FrankaSim(robot=self.robot, camera=False, table=False, reflexes=False)
            m = sim.world.model
            renderer = make_renderer(m, self.width, self.height)
        except Exception as e:  # no GL on this machine (or no display and no EGL/OSMesa)
            gl = os.environ.get("MUJOCO_GL", "default")
            self.error = (f"the arm view needs offscreen OpenGL (MUJOCO_GL={gl}) and this machine has none: "
                          f"{' '.join(str(e).split())[:300]}. Everything else works; install Mesa's EGL (libegl1) or "
                          "OSMesa and set MUJOCO_GL=egl or osmesa")
            raise NoGL(self.error) from e
        self._sim, self._renderer = sim, renderer
        names = {f"{sim.prefix}link{i + 1}": i for i in range(7)}
        for g in range(m.ngeom):
            body = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g]))
            if body in names:
                self._link_of_geom[g] = names[body]

    def image(self, q: np.ndarray, levels: np.ndarray) -> np.ndarray:
        """(height, width, 3) uint8: the arm at ``q`` with link ``j + 1`` coloured by ``levels[j]``."""
        import mujoco

        self._make()
        m, d = self._sim.world.model, self._sim.world.data
        d.qpos[:7] = np.asarray(q, dtype=np.float64)[:7]
        d.qvel[:] = 0.0
        mujoco.mj_forward(m, d)
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = (0.2, 0.0, 0.4)
        cam.distance, cam.azimuth, cam.elevation = 1.45, 140.0, -15.0
        r = self._renderer
        r.update_scene(d, cam)
        scene = r.scene
        for i in range(scene.ngeom):
            g = scene.geoms[i]
            if g.objtype == int(mujoco.mjtObj.mjOBJ_GEOM) and g.objid in self._link_of_geom:
                c = residual_colour(float(levels[self._link_of_geom[g.objid]]))
                g.rgba[:] = (*c, 1.0)
                g.matid = -1  # the colour, not the material's
        return r.render().copy()

    def png_data_url(self, q: np.ndarray, levels: np.ndarray) -> str:
        """The image as a ``data:image/png;base64,...`` URL (nothing fetched from anywhere)."""
        import cv2

        ok, png = cv2.imencode(".png", np.ascontiguousarray(self.image(q, levels)[:, :, ::-1]))  # OpenCV: BGR
        if not ok:
            raise RuntimeError("PNG encoding of the arm view failed")
        return "data:image/png;base64," + base64.b64encode(png.tobytes()).decode("ascii")

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


__all__ = ["ArmView", "NoGL", "RED_AT", "residual_colour"]
