"""One RGB-D pair from image files: a 16-bit depth PNG (and optionally its registered colour image) with intrinsics
given on the command line or in a JSON file — what a RealSense / Kinect / dataset frame looks like on disk.

Convention:
    ``depth`` PNG uint16 [H, W], 0 = invalid, in ``depth_unit``: "mm", "m", or metres per stored unit (a number,
    e.g. 0.0001 for a 1/10000 m depth scale). ``K`` from ``parse_intrinsics``: "fx,fy,cx,cy" (pixels, of the depth
    image) or a JSON file holding either ``{"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], "width": W, "height": H}``
    (the ``intrinsics.json`` of PNG folders, ``equipose.sources.folder``) or ``{"fx", "fy", "cx", "cy"}``.
    ``rgb``: BGR uint8 registered to the depth (read with OpenCV; any size — overlays use the depth's).
"""
from __future__ import annotations

import json
import pathlib

import numpy as np

from equipose.core.errors import SourceError
from equipose.sources.base import Frame, FrameSource

__all__ = ["RgbdPairSource", "parse_intrinsics", "parse_depth_unit"]


def parse_intrinsics(text) -> tuple:
    """"fx,fy,cx,cy" or a JSON file → (K [3, 3] float64, image_size (W, H) or None). Raises ``SourceError``."""
    text = str(text)
    parts = text.split(",")
    if len(parts) == 4:
        try:
            fx, fy, cx, cy = (float(v) for v in parts)
        except ValueError:
            raise SourceError(f"--intrinsics {text!r}: expected four numbers fx,fy,cx,cy or a JSON file") from None
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), None
    path = pathlib.Path(text)
    if not path.is_file():
        raise SourceError(f"--intrinsics {text!r} is neither fx,fy,cx,cy nor an existing JSON file")
    try:
        d = json.loads(path.read_text())
        if "K" in d:
            K = np.asarray(d["K"], np.float64).reshape(3, 3)
        else:
            K = np.array([[float(d["fx"]), 0.0, float(d["cx"])], [0.0, float(d["fy"]), float(d["cy"])],
                          [0.0, 0.0, 1.0]])
        size = (int(d["width"]), int(d["height"])) if "width" in d and "height" in d else None
    except (KeyError, TypeError, ValueError, json.JSONDecodeError) as e:
        raise SourceError(f"{path} is malformed ({type(e).__name__}: {e}); expected {{\"K\": [[fx,0,cx],[0,fy,cy],"
                          "[0,0,1]], \"width\": W, \"height\": H}} or {\"fx\", \"fy\", \"cx\", \"cy\"}") from None
    return K, size


def parse_depth_unit(text) -> object:
    """"mm", "m" or metres per stored unit (a positive number) → what ``Frame.depth_unit`` takes."""
    if text in ("mm", "m"):
        return text
    try:
        v = float(text)
    except (TypeError, ValueError):
        raise SourceError(f"--depth-unit {text!r}: expected mm, m or metres per stored unit (e.g. 0.0001)") from None
    if not v > 0:
        raise SourceError(f"--depth-unit must be positive metres per unit, got {text!r}")
    return v


class RgbdPairSource(FrameSource):
    """A one-frame source: depth PNG + optional colour image + intrinsics (see the module convention)."""

    def __init__(self, depth, K, *, rgb=None, depth_unit="mm", image_size=None):
        import cv2
        self.depth_path = pathlib.Path(depth)
        d = cv2.imread(str(self.depth_path), cv2.IMREAD_UNCHANGED)
        if d is None:
            raise SourceError(f"{self.depth_path} is not a readable image (a 16-bit depth PNG is expected)")
        if d.ndim != 2 or d.dtype != np.uint16:
            raise SourceError(f"{self.depth_path} holds {d.dtype} {d.shape}; a depth frame is one uint16 channel "
                              "(0 = invalid) — pass the depth image, not the colour one")
        colour = None
        if rgb is not None:
            colour = cv2.imread(str(rgb), cv2.IMREAD_COLOR)
            if colour is None:
                raise SourceError(f"{rgb} is not a readable colour image")
            if colour.shape[:2] != d.shape:
                colour = cv2.resize(colour, (d.shape[1], d.shape[0]), interpolation=cv2.INTER_AREA)
        self.frame = Frame(depth=d, K=np.asarray(K, np.float64), depth_unit=depth_unit, rgb=colour, index=0,
                           image_size=image_size, name=self.depth_path.stem)

    def __len__(self):
        return 1

    def __iter__(self):
        yield self.frame
