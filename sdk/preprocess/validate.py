"""Input validation: depth units → metres, intrinsics, boxes, masks and point arrays.

Convention:
    Depth frames are ``[H, W]`` arrays. ``depth_unit="mm"`` (the default, depthai/RealSense) means integer
    millimetres, 0 = invalid; ``"m"`` means float metres (0, NaN, Inf = invalid); a number means metres per stored
    unit (e.g. ``1e-4`` for YCB-Video's depth scale 10000). Units are declared, never guessed: values implausible for
    the declared unit raise ``DepthUnitError``.
    Intrinsics ``K`` are ``[3, 3]`` (OpenCV pinhole, pixel centres at integer coordinates). ``image_size=(W, H)`` is the
    size ``K`` was calibrated for; when the depth frame has another size of the same aspect ratio, ``K`` is rescaled.
    Boxes are ``(x, y, w, h)`` in pixels (x = column of the left edge, y = row of the top edge); masks are ``[H, W]``
    bool (or 0/non-zero) arrays. Points are ``[P, 3]`` float32 metres in the OpenCV camera frame (x right, y down,
    z forward).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from equipose.core.errors import (DepthDtypeError, DepthUnitError, EmptyDepthError, InvalidPointsError,
                                   RegionError)
from equipose.core.order_statistics import median
from equipose.core.units import metres_per_unit
# the intrinsics check lives in the core (sources use it too); re-exported here as part of preprocess's API
from equipose.core.intrinsics import CENTRE_TOLERANCE, FOCAL_RANGE, check_intrinsics  # noqa: F401

__all__ = ["PLAUSIBLE_DEPTH_M", "FOCAL_RANGE", "CENTRE_TOLERANCE", "depth_to_metres", "check_intrinsics", "check_box", "check_mask", "check_points",
           "check_regions", "region_bounds"]

PLAUSIBLE_DEPTH_M = (0.05, 30.0)  # median valid depth must fall in here for the declared unit to be believed


def _unit_scale(depth_unit) -> float:
    """metres per stored depth unit."""
    return metres_per_unit(depth_unit, "depth_unit", DepthUnitError)


def depth_to_metres(depth, depth_unit="mm", *, check_plausible: bool = True) -> np.ndarray:
    """Validate a depth frame and convert it to float32 metres (invalid pixels → 0).

    Convention: ``depth`` [H, W] (a trailing singleton channel is accepted), unit per ``depth_unit`` (see module doc).
    Returns [H, W] float32 metres, 0 = invalid.
    Raises ``DepthDtypeError`` (uint8, colour images, non-numeric), ``EmptyDepthError`` (empty or nothing valid),
    ``DepthUnitError`` (values implausible for the unit).
    """
    if depth is None:
        raise EmptyDepthError("depth is None; pass a [H, W] depth frame (e.g. cv2.imread(path, cv2.IMREAD_UNCHANGED))")
    depth = np.asarray(depth)
    if depth.ndim == 3 and depth.shape[2] == 1:
        depth = depth[:, :, 0]                                                  # [H, W, 1] → [H, W]
    if depth.dtype == np.uint8 or depth.dtype == np.int8:
        raise DepthDtypeError(
            f"depth is {depth.dtype} {depth.shape}: 8-bit images cannot hold depth. This usually means a 16-bit PNG "
            "was read with cv2.imread(path) — read it with cv2.imread(path, cv2.IMREAD_UNCHANGED) to get uint16 mm")
    if depth.ndim != 2:
        raise DepthDtypeError(f"depth must be a single-channel [H, W] array, got shape {depth.shape}"
                              + ("; this looks like a colour image — pass the depth frame instead" if depth.ndim == 3 else ""))
    if depth.size == 0:
        raise EmptyDepthError(f"depth frame is empty (shape {depth.shape}); check the source delivered a frame")
    if depth.dtype == np.bool_ or not (np.issubdtype(depth.dtype, np.integer) or np.issubdtype(depth.dtype, np.floating)):
        raise DepthDtypeError(f"depth dtype {depth.dtype} is not numeric; pass uint16 millimetres or float metres")
    scale = _unit_scale(depth_unit)
    if np.issubdtype(depth.dtype, np.unsignedinteger):                          # finite, ≥ 0, 0 stays 0
        d, n_valid = _unsigned_to_metres(depth, np.float32(scale))              # [H, W] metres, one compiled pass
    else:
        d = np.multiply(depth, np.float32(scale), dtype=np.float32)             # [H, W] metres
        d[~(np.isfinite(d) & (d > 0))] = 0.0                                    # [H, W] invalid → 0
        n_valid = int(np.count_nonzero(d))
    if n_valid == 0:
        raise EmptyDepthError(f"depth frame {depth.shape} has no valid pixel (all 0, negative, NaN or Inf); "
                              "check that the camera delivers depth and the scene is within its range")
    if check_plausible:
        sub = d[::8, ::8]                                                       # unit check on a 1/64 lattice
        sub = sub[sub > 0]
        med = median(sub if sub.size else d[d > 0])                             # sparse frames: every valid pixel
        lo, hi = PLAUSIBLE_DEPTH_M
        if not lo <= med <= hi:
            raw = med / scale
            hint = ""
            if med < lo and scale >= 1e-3:
                hint = " — values look like metres; pass depth_unit='m'" if raw < 30 else ""
            elif med > hi and scale >= 1.0:
                hint = " — values look like millimetres; pass depth_unit='mm'"
            raise DepthUnitError(
                f"median valid depth is {raw:.4g} stored units = {med:.4g} m with depth_unit={depth_unit!r}, outside the "
                f"plausible {lo}–{hi} m{hint}. Declare the unit the frame really uses (depth_unit='mm', 'm' or metres "
                "per unit as a number)")
    return d


@njit(cache=True)
def _unsigned_to_metres(depth, scale):
    """(``depth`` [H, W] unsigned ints × ``scale`` as float32 metres [H, W], the number of non-zero pixels)."""
    H, W = depth.shape
    d = np.empty((H, W), np.float32)
    n = 0
    for r in range(H):
        for c in range(W):
            v = depth[r, c]
            d[r, c] = np.float32(v) * scale
            n += v != 0
    return d, n


def check_box(box, shape) -> tuple:
    """Validate ``(x, y, w, h)`` against a frame of ``shape`` (H, W); clip it to the frame.

    Returns (x0, y0, x1, y1) int with x1/y1 exclusive. Raises ``RegionError`` if malformed, empty or outside the image.
    """
    H, W = int(shape[0]), int(shape[1])
    try:
        vals = np.asarray(box, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise RegionError(f"box must be (x, y, w, h) numbers, got {box!r}") from None
    if vals.shape != (4,) or not np.all(np.isfinite(vals)):
        raise RegionError(f"box must be 4 finite numbers (x, y, w, h) in pixels, got {box!r}")
    x, y, w, h = vals
    if w <= 0 or h <= 0:
        raise RegionError(f"box {tuple(vals)} has non-positive width/height; boxes are (x, y, w, h), not (x0, y0, x1, y1)")
    x0, y0 = int(math.floor(x)), int(math.floor(y))
    x1, y1 = int(math.ceil(x + w)), int(math.ceil(y + h))
    cx0, cy0, cx1, cy1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if cx1 - cx0 < 1 or cy1 - cy0 < 1:
        raise RegionError(f"box (x={x:g}, y={y:g}, w={w:g}, h={h:g}) lies outside the {W}×{H} image; boxes are (x, y, w, h) "
                          "in pixels of the depth frame (rescale boxes from another image size first)")
    return cx0, cy0, cx1, cy1


def region_bounds(region: dict, shape) -> tuple:
    """(x0, y0, x1, y1) pixels, x1 and y1 exclusive, of an object's region {"box", "mask"} in a frame of ``shape``
    (H, W): the box when given, else the mask's bounding box. Raises ``RegionError`` (``check_box``, ``check_mask``)."""
    if region.get("box") is not None:
        return check_box(region["box"], shape)
    m = check_mask(region["mask"], shape)                                       # [H, W] bool, not empty
    rows, cols = np.flatnonzero(m.any(1)), np.flatnonzero(m.any(0))             # occupied rows, columns
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1


def check_mask(mask, shape) -> np.ndarray:
    """Validate a mask for a frame of ``shape`` (H, W). Returns [H, W] bool. Raises ``RegionError``."""
    m = np.asarray(mask)
    if not (m.dtype == np.bool_ or np.issubdtype(m.dtype, np.integer) or np.issubdtype(m.dtype, np.floating)):
        raise RegionError(f"mask dtype {m.dtype} is not boolean or numeric; pass an [H, W] bool array (or 0/non-zero "
                          "numbers, e.g. a mask image read with cv2.IMREAD_GRAYSCALE)")
    if np.issubdtype(m.dtype, np.floating) and not np.all(np.isfinite(m)):
        raise RegionError("mask contains NaN/Inf; pass an [H, W] bool array (e.g. np.nan_to_num(mask) > 0.5)")
    if m.ndim == 3 and m.shape[2] in (1, 3, 4):
        m = m[:, :, 0]                                                          # [H, W, C] → [H, W] (first channel)
    if m.shape != tuple(shape[:2]):
        raise RegionError(f"mask shape {np.asarray(mask).shape} does not match the depth frame {tuple(shape[:2])}; "
                          "resize it with cv2.resize(..., interpolation=cv2.INTER_NEAREST)")
    m = m.astype(bool)
    if not m.any():
        raise RegionError("mask is empty (no non-zero pixel); pass a mask that covers the object")
    return m


def check_points(points, name: str = "points") -> np.ndarray:
    """Validate a point array. Convention: [P, 3] metres. Returns float64 [P, 3]. Raises ``InvalidPointsError``."""
    try:
        raw = np.asarray(points)
    except (TypeError, ValueError):                                             # ragged nested lists
        raise InvalidPointsError(f"{name} must be a numeric [P, 3] array of metres") from None
    if raw.dtype == np.bool_ or not (np.issubdtype(raw.dtype, np.integer) or np.issubdtype(raw.dtype, np.floating)
                                     or raw.dtype == object):
        raise InvalidPointsError(f"{name} have dtype {raw.dtype}; pass real numbers (float metres)")
    try:
        p = np.asarray(raw, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidPointsError(f"{name} must be a numeric [P, 3] array of metres") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidPointsError(f"{name} must be [P, 3] (x, y, z rows), got shape {p.shape}")
    bad = ~np.all(np.isfinite(p), axis=1)                                       # [P]
    if bad.any():
        raise InvalidPointsError(f"{name} contain {int(bad.sum())} row(s) with NaN/Inf (first at index "
                                 f"{int(np.argmax(bad))}); drop invalid points first, e.g. p[np.isfinite(p).all(1)]")
    return p


def check_regions(boxes=None, masks=None) -> list:
    """Per-object regions ``[{"box": (x, y, w, h) | None, "mask": [H, W] | None}]`` from parallel lists.

    Convention: ``boxes`` list of (x, y, w, h) pixels and/or ``masks`` list of [H, W] arrays (same length if both);
    neither gives one whole-frame region. Raises ``RegionError`` on non-lists or a length mismatch.
    """
    try:
        boxes = list(boxes) if boxes is not None else None
        masks = list(masks) if masks is not None else None
    except TypeError:
        raise RegionError("boxes must be a list of (x, y, w, h) and masks a list of [H, W] arrays, one per "
                          "object (use predict(..., box=...) for a single object)") from None
    if boxes is not None and masks is not None and len(boxes) != len(masks):
        raise RegionError(f"{len(boxes)} boxes but {len(masks)} masks; pass one of each per object")
    n = len(boxes) if boxes is not None else (len(masks) if masks is not None else 1)
    return [{"box": None if boxes is None else boxes[i], "mask": None if masks is None else masks[i]}
            for i in range(n)]
