"""Offscreen rendering of camera views: one call per image, the skybox skipped where nothing of it can show, and
one OpenGL context shared by many simulations of the same scene.

MuJoCo's classic renderer (``mujoco.Renderer``: an OpenGL context and an ``MjrContext`` holding the model's meshes
and textures) draws one scene per ``mjr_render`` call. Two things make camera images of this project cheaper
without changing a single pixel:

- **The skybox only where it can show.** ``mjr_render`` draws the skybox after the opaque geometry, as a large
  textured cylinder around the camera; its fragments only land where nothing nearer was drawn. On a software
  rasteriser (Mesa's llvmpipe, the usual EGL backend of a headless machine) that cylinder is about half of the cost
  of a wrist-camera frame, although a wrist camera looking at the table never sees the sky. :func:`sky_hidden`
  proves from the scene's camera frustum that one opaque box face (the table top) covers every pixel, nearer than
  the skybox; the frame is then rendered without the skybox pass, which would have failed the depth test at every
  sample. Images are identical (tests compare them, pixel for pixel, with the skybox drawn).
- **One context for many robots.** A batch of robots (``FrankaVectorEnv``) has one model per robot, but their meshes,
  textures and materials are the same. :class:`SharedRenderers` gives all their worlds one renderer per image size
  (one OpenGL context and framebuffer instead of one per robot, and no context switch between robots); each robot's
  scene is built from its own model and data. Every image is drawn into the same framebuffer rectangle as a
  robot's own renderer draws it: drawing several robots into tiles of one larger framebuffer and reading it back
  once was measured too, and is not used, because a tile away from the origin rasterises a few edge pixels
  differently (by one grey level) and is no faster, the cost being the rasterisation itself.
"""

from __future__ import annotations

import copy
import hashlib
import os

import mujoco
import numpy as np

_BOX = int(mujoco.mjtGeom.mjGEOM_BOX)
_SKYBOX = int(mujoco.mjtRndFlag.mjRND_SKYBOX)
_CAT_ALL = int(mujoco.mjtCatBit.mjCAT_ALL)
_FIXED = int(mujoco.mjtCamera.mjCAMERA_FIXED)
_FREE = int(mujoco.mjtCamera.mjCAMERA_FREE)
_OPAQUE = 0.995  # mjr_render draws a geom with alpha below this as transparent

# the frustum tested is this much larger than the one drawn, and a hit must lie this far inside the face (relative to
# the face size): margins far above the float32 rounding of OpenGL's transforms
_FRUSTUM_MARGIN = 0.01
_FACE_MARGIN = 1e-4


def _frustum_rays(scene: mujoco.MjvScene, aspect: float) -> tuple[tuple[float, ...], list[tuple[float, ...]],
                                                                  float, float] | None:
    """(camera position, the four corner directions of a slightly enlarged view frustum, scaled so that a point at
    parameter t along a ray lies at view depth t * near, near, far) in world coordinates, as ``mjr_render`` sets up
    its view (the mean of the scene's two cameras); None for an orthographic camera."""
    cam = mujoco.mjv_averageCamera(scene.camera[0], scene.camera[1])
    if cam.orthographic:
        return None
    near, far = float(cam.frustum_near), float(cam.frustum_far)
    top, bottom = float(cam.frustum_top), float(cam.frustum_bottom)
    # mjr_render's half width: frustum_width when set, else from the viewport's aspect ratio; take the larger
    hw = max(float(cam.frustum_width), 0.5 * aspect * (top - bottom))
    c = float(cam.frustum_center)
    ex, ey = _FRUSTUM_MARGIN * hw, _FRUSTUM_MARGIN * (top - bottom)
    f = [float(v) for v in cam.forward]
    u = [float(v) for v in cam.up]
    r = [f[1] * u[2] - f[2] * u[1], f[2] * u[0] - f[0] * u[2], f[0] * u[1] - f[1] * u[0]]  # forward x up
    rays = []
    for x in (c - hw - ex, c + hw + ex):
        for y in (bottom - ey, top + ey):
            rays.append(tuple(near * f[k] + x * r[k] + y * u[k] for k in range(3)))
    return tuple(float(v) for v in cam.pos), rays, near, far


def sky_hidden(scene: mujoco.MjvScene, width: int, height: int) -> bool:
    """Whether an updated scene's view (``width`` x ``height`` pixels) is entirely covered by one face of one opaque
    box geom, between the near plane and half the far distance (the skybox is drawn at 0.7 x far), so that the skybox
    cannot show at any pixel or multisample.

    Sufficient, not necessary: the four corner rays of a frustum 1 % larger than the drawn one must hit the same
    face, inside it by 1e-4 of its size and at a depth of at least 1.001 x near; a face and the frustum's section of
    its plane are convex, so every ray in between hits it too."""
    rays = _frustum_rays(scene, width / height)
    if rays is None:
        return False
    p, dirs, near, far = rays
    tmax = 0.5 * far / near
    for g in range(scene.ngeom):
        geom = scene.geoms[g]
        if geom.type != _BOX or geom.rgba[3] < _OPAQUE:
            continue
        m = geom.mat.tolist()  # rows: world axes; columns: the box's axes
        gp, s = geom.pos.tolist(), geom.size.tolist()
        dp = (p[0] - gp[0], p[1] - gp[1], p[2] - gp[2])
        pl = [m[0][k] * dp[0] + m[1][k] * dp[1] + m[2][k] * dp[2] for k in range(3)]  # camera in the box frame
        dls = [[m[0][k] * d[0] + m[1][k] * d[1] + m[2][k] * d[2] for k in range(3)] for d in dirs]
        for k in range(3):
            for sign in (1.0, -1.0):
                h = sign * s[k]
                if sign * pl[k] <= abs(h):  # the camera is not outside this face's side of the box
                    continue
                ok = True
                for dl in dls:
                    if sign * dl[k] >= 0.0:
                        ok = False
                        break
                    t = (h - pl[k]) / dl[k]
                    if not (1.001 <= t <= tmax):
                        ok = False
                        break
                    for j in range(3):
                        if j != k and abs(pl[j] + t * dl[j]) > s[j] * (1.0 - _FACE_MARGIN):
                            ok = False
                            break
                    if not ok:
                        break
                if ok:
                    return True
    return False


def render_view(renderer: mujoco.Renderer, model: mujoco.MjModel, data: mujoco.MjData, camera: int | str,
                out: np.ndarray | None = None, option: mujoco.MjvOption | None = None) -> np.ndarray:
    """The (height, width, 3) uint8 image of ``camera`` (id or name; -1 the free camera) of ``model``/``data``,
    drawn by ``renderer`` (whose context may belong to another model with the same visual assets), the skybox
    pass skipped when :func:`sky_hidden` proves it invisible. Returns ``out`` when given, else a new array."""
    cam_id = camera if isinstance(camera, (int, np.integer)) else mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA,
                                                                                   camera)
    if isinstance(camera, str) and cam_id < 0:
        raise ValueError(f"no camera {camera!r} in the model")
    cam = mujoco.MjvCamera()
    if cam_id < 0:
        cam.type = _FREE
        mujoco.mjv_defaultFreeCamera(model, cam)
    else:
        cam.type = _FIXED
        cam.fixedcamid = int(cam_id)
    scene = renderer.scene
    mujoco.mjv_updateScene(model, data, option if option is not None else _DEFAULT_OPTION, None, cam, _CAT_ALL,
                           scene)
    flags = scene.flags
    sky = flags[_SKYBOX]
    if sky and sky_hidden(scene, renderer.width, renderer.height):
        flags[_SKYBOX] = 0
        try:
            return renderer.render(out=out)
        finally:
            flags[_SKYBOX] = sky
    return renderer.render(out=out)


_DEFAULT_OPTION = mujoco.MjvOption()


def make_renderer(model: mujoco.MjModel, width: int, height: int) -> mujoco.Renderer:
    """An offscreen ``mujoco.Renderer`` (headless: EGL or OSMesa, see :func:`ensure_gl_backend`) of ``width`` x
    ``height`` pixels, with a clear error when the machine cannot render.

    Its offscreen framebuffer is the image's size, not the model's (``<visual><global offwidth offheight>``, 640 x
    480 in this project's scenes): ``mjr_render`` clears, and the readback resolves, the multisampled framebuffer,
    whose size a software rasteriser pays for at every frame (a 64 x 48 frame: 8 % less CPU time on Mesa's llvmpipe,
    the same pixels, as the image is drawn in the framebuffer's corner either way). The renderer holds a copy of
    the model with that size (meshes, textures and everything else the same). Only smaller: an image larger than the
    model's framebuffer gets mujoco.Renderer's error, which says how to enlarge it."""
    ensure_gl_backend()
    vis = model.vis.global_
    if 0 < width <= vis.offwidth and 0 < height <= vis.offheight and (width, height) != (vis.offwidth, vis.offheight):
        model = copy.copy(model)
        model.vis.global_.offwidth, model.vis.global_.offheight = int(width), int(height)
    try:
        return mujoco.Renderer(model, height, width)
    except Exception as e:  # pragma: no cover - depends on the machine
        raise RuntimeError(
            f"offscreen rendering failed (MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}): {e}. MuJoCo picks its "
            "OpenGL backend when it is first imported: on a machine without a display install Mesa (EGL or "
            "OSMesa) and set MUJOCO_GL=egl (or osmesa) in the environment, or import franka_vs_gym before "
            "mujoco so that it can choose EGL for you.") from e


def visual_fingerprint(model: mujoco.MjModel) -> str:
    """A digest of everything of a model that ``MjrContext`` uploads or reads (meshes, textures, materials, height
    fields, skins, flexes, visual quality and offscreen size): two models with the same fingerprint can be drawn
    through one context."""
    h = hashlib.sha1()
    for name in ("mesh_vert", "mesh_normal", "mesh_face", "mesh_facenormal", "mesh_texcoord", "mesh_facetexcoord",
                 "mesh_vertadr", "mesh_vertnum", "mesh_faceadr", "mesh_facenum", "mesh_graph", "mesh_polynum",
                 "tex_type", "tex_width", "tex_height", "tex_nchannel", "tex_adr", "tex_data", "mat_texid",
                 "mat_texuniform", "mat_texrepeat", "hfield_size", "hfield_nrow", "hfield_ncol", "hfield_data",
                 "skin_vert", "skin_face", "skin_texcoord", "flex_vert", "flex_elem"):
        a = getattr(model, name, None)
        if a is not None:
            a = np.ascontiguousarray(a)
            h.update(name.encode())
            h.update(str(a.shape).encode())
            h.update(a.tobytes())
    vis = model.vis
    h.update(repr((vis.quality.shadowsize, vis.quality.offsamples, vis.quality.numslices, vis.quality.numstacks,
                   vis.quality.numquads, vis.global_.offwidth, vis.global_.offheight, vis.global_.fovy,
                   vis.global_.linewidth, vis.map.znear, vis.map.zfar, vis.map.fogstart, vis.map.fogend,
                   vis.map.haze, vis.map.shadowclip, vis.map.shadowscale, tuple(vis.rgba.fog), tuple(vis.rgba.haze),
                   model.stat.extent)).encode())
    return h.hexdigest()


class SharedRenderers:
    """Offscreen renderers shared by the worlds of many simulations of one scene (a batch of robots): one
    ``mujoco.Renderer`` (OpenGL context, framebuffer, uploaded meshes and textures) per image size, made at the first
    request, for every model whose :func:`visual_fingerprint` equals the first one's.

    ``SimWorld.share_renderers(pool)`` makes a world draw through the pool; its images are those of its own
    renderers (each scene is built from the world's own model and data and drawn into the same framebuffer
    rectangle). Used from one thread; ``close()`` frees the contexts."""

    def __init__(self) -> None:
        self._model: mujoco.MjModel | None = None
        self._fingerprint: str | None = None
        self._renderers: dict[tuple[int, int], mujoco.Renderer] = {}

    def accepts(self, model: mujoco.MjModel) -> bool:
        """Whether ``model`` can be drawn through this pool (the first model offered sets its assets)."""
        fp = visual_fingerprint(model)
        if self._fingerprint is None:
            self._model, self._fingerprint = model, fp
            return True
        return fp == self._fingerprint

    def renderer(self, width: int, height: int) -> mujoco.Renderer:
        if self._model is None:
            raise RuntimeError("no model offered to the shared renderers yet (SimWorld.share_renderers)")
        key = (int(width), int(height))
        r = self._renderers.get(key)
        if r is None:
            r = self._renderers[key] = make_renderer(self._model, *key)
        return r

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers.clear()


def ensure_gl_backend() -> str:
    """Make sure offscreen rendering has a headless OpenGL backend on a machine without a display; returns the
    backend name.

    MuJoCo picks its backend from MUJOCO_GL when it is first imported (franka_vs_gym sets EGL before that when no
    display is present). If MuJoCo was imported first and fell back to GLFW, which needs a display, the EGL context
    is swapped in here, before the first renderer is made.
    """
    if os.environ.get("DISPLAY"):
        return os.environ.get("MUJOCO_GL", "glfw")
    if "MUJOCO_GL" not in os.environ:
        os.environ["MUJOCO_GL"] = "egl"
    from mujoco.rendering.classic import gl_context

    current = getattr(gl_context, "GLContext", None)
    if current is not None and "glfw" in getattr(current, "__module__", ""):
        os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
        try:
            from mujoco.egl import GLContext as EGLContext
        except Exception as e:  # pragma: no cover - depends on the machine
            raise RuntimeError(f"no display and no EGL for headless rendering ({e}); install Mesa's EGL "
                               "(libegl1) or set MUJOCO_GL=osmesa before importing mujoco") from e
        gl_context.GLContext = EGLContext
        return "egl"
    return os.environ.get("MUJOCO_GL", "glfw")


__all__ = ["SharedRenderers", "ensure_gl_backend", "make_renderer", "render_view", "sky_hidden",
           "visual_fingerprint"]
