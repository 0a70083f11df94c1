"""AprilTag 36h11 targets: geometry, detection in images, pose by PnP, and the fast "ideal features" mode.

Tag frame o: origin at the tag centre, z out of the tag's printed face (towards a camera that sees it), x to the
right and y up as the tag is printed. Corners are ordered as OpenCV's detector returns them and as its IPPE-square
PnP expects: 0 top-left (-s/2, +s/2), 1 top-right (+s/2, +s/2), 2 bottom-right (+s/2, -s/2),
3 bottom-left (-s/2, -s/2), with s the side of the black square (the tag "size", as in ViSP).

Detector choice: OpenCV's aruco module (DICT_APRILTAG_36h11), sub-pixel corners, with an AprilTag-refined second
pass for the views the first misses. It ships with the
opencv-python-headless dependency (no extra compiled package), decodes the same 36h11 family, and on the rendered
images used here detects the tag in well under the 15 ms budget per 320x240 frame (see scripts/bench.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from franka_vs_gym.vision.camera import CameraIntrinsics


def tag_corners(size: float) -> np.ndarray:
    """Corners (4, 3) of a tag of side ``size`` (m) in the tag frame, in detection order."""
    if not size > 0:
        raise ValueError(f"tag size must be > 0 m, got {size}")
    h = size / 2
    return np.array([[-h, h, 0.0], [h, h, 0.0], [h, -h, 0.0], [-h, -h, 0.0]])


@dataclass
class TagDetection:
    """One detected tag: its id and its 4 corners (4, 2) in pixels, in detection order."""

    tag_id: int
    corners: np.ndarray


def refine_corners(gray: np.ndarray, corners: np.ndarray, n_samples: int = 16) -> np.ndarray:
    """Sub-pixel corners (4, 2) of a tag's black square from straight lines fitted to its four edges.

    ``corners`` (4, 2) pixels, in order around the square (as the detector returns them), seed the search. Along
    each side, ``n_samples`` points between 20% and 80% of its length are moved onto the edge: the intensity
    profile across the side (bilinear, 0.25 px steps, up to 0.6 tag cell either side, dark inside to bright
    outside) is normalised between its two plateaus and the edge is where the area under the dark part ends, which
    is exact for any symmetric blur of a step. A total-least-squares line through these points is fitted per side
    and adjacent lines are intersected. Corner-based refinements (OpenCV's cornerSubPix) are biased towards the
    inside of an L-shaped corner by 0.1-0.2 px on rendered tags; this is not (0.03 px mean error at 320x240).

    Sides with fewer than 3 edge points of enough contrast (40 grey levels) leave the corners unchanged.
    """
    import cv2

    g = np.ascontiguousarray(gray, dtype=np.float32)
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    centre = c.mean(axis=0)
    side = float(np.mean(np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1)))
    reach = float(np.clip(0.6 * side / 8, 1.5, 4.0))  # the black border is one of the 8 cells of the square
    s = np.arange(-reach, reach + 1e-9, 0.25)
    t = np.linspace(0.2, 0.8, n_samples)
    lines = []
    for k in range(4):
        a, b = c[k], c[(k + 1) % 4]
        length = np.linalg.norm(b - a)
        if length < 1e-6:
            return c
        d = (b - a) / length
        n = np.array([-d[1], d[0]])
        if np.dot(n, (a + b) / 2 - centre) < 0:
            n = -n  # outwards: from the black square to the white border
        P = a + t[:, None] * (b - a)
        pts = P[:, None, :] + s[None, :, None] * n
        prof = cv2.remap(g, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32), cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        lo = prof[:, :3].mean(axis=1, keepdims=True)
        hi = prof[:, -3:].mean(axis=1, keepdims=True)
        good = (hi - lo)[:, 0] > 40.0
        dark = 1.0 - np.clip((prof - lo) / np.maximum(hi - lo, 1e-6), 0.0, 1.0)
        edge = -reach + 0.25 * (dark.sum(axis=1) - 0.5 * (dark[:, 0] + dark[:, -1]))  # trapezoid rule
        E = (P + edge[:, None] * n)[good]
        if len(E) < 3:
            return c
        m = E.mean(axis=0)
        lines.append((m, np.linalg.svd(E - m)[2][0]))
    out = np.empty((4, 2))
    for k in range(4):
        (p1, d1), (p2, d2) = lines[k - 1], lines[k]
        A = np.column_stack([d1, -d2])
        if abs(np.linalg.det(A)) < 1e-6:
            return c
        out[k] = p1 + np.linalg.solve(A, p2 - p1)[0] * d1
    if np.max(np.linalg.norm(out - c, axis=1)) > 2.0:  # a line fit went astray (occlusion, clutter)
        return c
    return out


class TagDetector:
    """AprilTag 36h11 detector on RGB or grayscale uint8 images.

    Two passes: OpenCV's contour-based quad search with sub-pixel corner refinement (0.26 px mean error on rendered
    frames), then, for a tag the first pass missed, the AprilTag-style quad refinement, which finds squares whose
    contour the first pass breaks up at some oblique views, followed by a sub-pixel corner search (OpenCV's
    cornerSubPix). With ``refine`` (default) the corners are then fitted to the tag's edges
    (:func:`refine_corners`: 0.03 px mean error)."""

    def __init__(self, refine: bool = True) -> None:
        import cv2

        self._cv2 = cv2
        self._edge_refine = refine
        dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
        params = cv2.aruco.DetectorParameters()
        if refine:
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self._det = cv2.aruco.ArucoDetector(dictionary, params)
        fallback = cv2.aruco.DetectorParameters()
        fallback.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
        self._fallback = cv2.aruco.ArucoDetector(dictionary, fallback)

    def _gray(self, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image)
        if img.dtype != np.uint8 or img.ndim not in (2, 3):
            raise ValueError(f"expected a uint8 image (H, W) or (H, W, 3), got {img.dtype} {img.shape}")
        return self._cv2.cvtColor(img, self._cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img

    def _run(self, detector, gray: np.ndarray) -> list[TagDetection]:
        corners, ids, _ = detector.detectMarkers(gray)
        if ids is None:
            return []
        if detector is self._fallback:
            # The AprilTag-style quad fit leaves corners up to ~1.1 px off on rendered frames; a sub-pixel corner
            # search in a 7x7 window brings them to ~0.3 px, like the first pass (measured on the 100 start views
            # of scripts/eval_servo.py at 320x240).
            cv2 = self._cv2
            crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.01)
            corners = [cv2.cornerSubPix(gray, np.ascontiguousarray(c, dtype=np.float32).reshape(4, 1, 2), (3, 3),
                                        (-1, -1), crit) for c in corners]
        out = [TagDetection(int(i), np.asarray(c, dtype=np.float64).reshape(4, 2))
               for i, c in zip(ids.ravel(), corners, strict=True)]
        if self._edge_refine:
            for d in out:
                d.corners = refine_corners(gray, d.corners)
        return out

    def detect(self, image: np.ndarray) -> list[TagDetection]:
        """All tags found by the first pass (or by the second when the first finds none)."""
        gray = self._gray(image)
        return self._run(self._det, gray) or self._run(self._fallback, gray)

    def find(self, image: np.ndarray, tag_id: int) -> TagDetection | None:
        """The tag ``tag_id``, trying the second pass if the first misses it."""
        gray = self._gray(image)
        for dets in (self._run(self._det, gray), None):
            if dets is None:
                dets = self._run(self._fallback, gray)
            for d in dets:
                if d.tag_id == tag_id:
                    return d
        return None


def estimate_pose(corners_px: np.ndarray, size: float, intrinsics: CameraIntrinsics) -> np.ndarray:
    """cMo (4, 4) of a tag from its 4 detected corners (4, 2) in pixels: IPPE-square PnP (no distortion), then
    Levenberg-Marquardt minimisation of the reprojection error."""
    import cv2

    c = np.asarray(corners_px, dtype=np.float64).reshape(4, 2)
    if not np.isfinite(c).all():
        raise ValueError("tag corners contain NaN or inf")
    obj = tag_corners(size)
    ok, rvec, tvec = cv2.solvePnP(obj, c, intrinsics.K, None, flags=cv2.SOLVEPNP_IPPE_SQUARE)
    if not (ok and np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        # IPPE-square degenerates to NaN for an exactly fronto-parallel square (the very pose servoing converges
        # to); the globally optimal SQPnP solves that case exactly.
        ok, rvec, tvec = cv2.solvePnP(obj, c, intrinsics.K, None, flags=cv2.SOLVEPNP_SQPNP)
    if not (ok and np.isfinite(rvec).all() and np.isfinite(tvec).all()):
        raise ValueError("PnP failed for these corners")
    # IPPE is a closed form from the homography, not the reprojection-error minimum: near the fronto-parallel goal
    # it leaves 1-2 deg of tilt error from 0.05 px corner errors; Levenberg-Marquardt polishing removes it.
    r2, t2 = cv2.solvePnPRefineLM(obj, c, intrinsics.K, None, rvec.copy(), tvec.copy())
    if np.isfinite(r2).all() and np.isfinite(t2).all() and t2.ravel()[2] > 0:
        rvec, tvec = r2, t2
    M = np.eye(4)
    M[:3, :3] = cv2.Rodrigues(rvec)[0]
    M[:3, 3] = tvec.ravel()
    return M


@dataclass
class TagMeasurement:
    """What the camera measures of one tag: corners (4, 2) in pixels and in normalized coordinates, depths Z (4,)
    of the corners in m, the pose cMo (4, 4), and whether the tag is seen (all 4 corners in the image)."""

    corners_px: np.ndarray
    corners_xy: np.ndarray
    depths: np.ndarray
    cMo: np.ndarray
    visible: bool


def ideal_measurement(cMo: np.ndarray, size: float, intrinsics: CameraIntrinsics, *, noise_px: float = 0.0,
                      dropout: float = 0.0, margin_px: float = 0.0,
                      rng: np.random.Generator | None = None) -> TagMeasurement:
    """The "ideal features" mode: project the true tag corners with the camera model, orders of magnitude faster
    than rendering and detecting. Optional white pixel noise (std ``noise_px``) and dropout (probability the tag is
    missed in this frame). The tag is visible when it is in front of the camera, faces it, and all corners are in
    the image (``margin_px`` from the border)."""
    cMo = np.asarray(cMo, dtype=np.float64)
    if cMo.shape != (4, 4) or not np.isfinite(cMo).all():
        raise ValueError("cMo must be a finite 4x4 pose")
    uv, xy, Z, vis = project_tag(cMo[None], size, intrinsics, margin_px)
    if not ((Z[0] > 1e-6).all() and cMo[2, 2] < 0):  # behind the camera or not facing it
        return TagMeasurement(uv[0], xy[0], Z[0], cMo, False)
    uv, xy, Z = uv[0], xy[0], Z[0]
    visible = bool(vis[0])
    if rng is not None and dropout > 0 and rng.random() < dropout:
        visible = False
    if noise_px > 0:
        if rng is None:
            raise ValueError("pixel noise needs a random generator (rng)")
        uv = uv + rng.normal(0.0, noise_px, uv.shape)
        xy = intrinsics.to_normalized(uv)
    return TagMeasurement(uv, xy, Z, cMo, visible)


_min, _all = np.minimum.reduce, np.logical_and.reduce


def project_tag(cMo: np.ndarray, size: float, intrinsics: CameraIntrinsics,
                margin_px: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ideal projection of the corners of N tags at once (the formula of :func:`ideal_measurement`, which calls it
    with N = 1, and of the batched environments): ``cMo`` (N, 4, 4) poses of the tags in the camera frame c.

    Returns (uv (N, 4, 2) pixels, xy (N, 4, 2) normalized coordinates, Z (N, 4) corner depths in m, visible (N,)
    bool): a tag is visible when it is in front of the camera (every Z > 1 um), faces it (its z axis towards the
    camera) and all corners are in the image, ``margin_px`` from the border; uv and xy are zeros where a tag is
    behind the camera or not facing it."""
    # (ufunc reductions called directly: this runs at every step of the visual environments, also with N = 1)
    P = np.matmul(tag_corners_T(size).T, cMo[:, :3, :3].swapaxes(1, 2))
    P += cMo[:, None, :3, 3]
    Z = P[:, :, 2]
    ok = (_min(Z, axis=1) > 1e-6) & (cMo[:, 2, 2] < 0)
    f, c, hi = intrinsics.pixel_arrays
    if ok.all():
        xy = P[:, :, :2] / Z[:, :, None]
        uv = xy * f + c
    else:
        uv = np.zeros(P.shape[:2] + (2,))
        xy = np.zeros_like(uv)
        xy[ok] = P[ok, :, :2] / Z[ok, :, None]
        uv[ok] = xy[ok] * f + c
    # every coordinate inside [-0.5 + margin, hi - margin] (NaN fails), one comparison per side
    inside = uv >= -0.5 + margin_px
    inside &= uv <= (hi - margin_px if margin_px else hi)
    visible = ok & _all(inside.reshape(len(uv), 8), axis=1)
    return uv, xy, Z, visible


@lru_cache(maxsize=32)
def tag_corners_T(size: float) -> np.ndarray:
    """tag_corners(size).T (3, 4), cached and read-only."""
    c = np.ascontiguousarray(tag_corners(size).T)
    c.flags.writeable = False
    return c


def detected_measurement(image: np.ndarray, detector: TagDetector, tag_id: int, size: float,
                         intrinsics: CameraIntrinsics) -> TagMeasurement:
    """Measurement from a rendered image: detection, then pose by PnP; depths from the estimated pose."""
    det = detector.find(image, tag_id)
    if det is None:
        return TagMeasurement(np.zeros((4, 2)), np.zeros((4, 2)), np.zeros(4), np.eye(4), False)
    cMo = estimate_pose(det.corners, size, intrinsics)
    Z = (tag_corners(size) @ cMo[:3, :3].T + cMo[:3, 3])[:, 2]
    return TagMeasurement(det.corners, intrinsics.to_normalized(det.corners), Z, cMo, True)
