"""Textures the package makes itself: AprilTag 36h11 markers rendered with OpenCV's aruco module.

Images are written once per tag id to a cache folder (``$FRANKA_VS_GYM_CACHE`` or ``~/.cache/franka_vs_gym``) and
reused; nothing is downloaded.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

CELL_PX = 32  # pixels per tag cell in the texture
TAG_CELLS = 8  # 6x6 data cells + 1-cell black border on each side
BORDER_CELLS = 1  # white quiet zone around the black square, in cells


def cache_dir() -> Path:
    d = Path(os.environ.get("FRANKA_VS_GYM_CACHE", Path.home() / ".cache" / "franka_vs_gym"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def tag_image(tag_id: int) -> np.ndarray:
    """Grayscale uint8 image of AprilTag 36h11 ``tag_id`` with a one-cell white border: (10*CELL_PX)^2 pixels."""
    import cv2

    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    n = dictionary.bytesList.shape[0]
    if not 0 <= int(tag_id) < n:
        raise ValueError(f"tag id must be in 0..{n - 1} for family 36h11, got {tag_id}")
    inner = cv2.aruco.generateImageMarker(dictionary, int(tag_id), TAG_CELLS * CELL_PX)
    b = BORDER_CELLS * CELL_PX
    return cv2.copyMakeBorder(inner, b, b, b, b, cv2.BORDER_CONSTANT, value=255)


def tag_texture_png(tag_id: int) -> Path:
    """Path of a PNG texture of the tag (made on first use)."""
    import cv2

    p = cache_dir() / f"tag36h11_{int(tag_id):05d}.png"
    if not p.exists():
        img = tag_image(tag_id)
        tmp = p.with_suffix(f".{os.getpid()}.tmp.png")
        cv2.imwrite(str(tmp), cv2.cvtColor(img, cv2.COLOR_GRAY2RGB))
        tmp.replace(p)
    return p
