"""Depth frame → object points: validation, cropping, cleaning, and the model-input preparation.

Convention:
    Depth frames are ``[H, W]`` arrays. ``depth_unit="mm"`` (the default, depthai/RealSense) means integer
    millimetres, 0 = invalid; ``"m"`` means float metres (0, NaN, Inf = invalid); a number means metres per stored
    unit (e.g. ``1e-4`` for YCB-Video's depth scale 10000). Units are declared, never guessed: values implausible for
    the declared unit raise ``DepthUnitError``.
    Intrinsics ``K`` are ``[3, 3]`` (OpenCV pinhole, pixel centres at integer coordinates). ``image_size=(W, H)`` is the
    size ``K`` was calibrated for; when the depth frame has another size of the same aspect ratio, ``K`` is rescaled.
    Boxes are ``(x, y, w, h)`` in pixels (x = column of the left edge, y = row of the top edge); masks are ``[H, W]``
    bool (or 0/non-zero) arrays. Points are ``[P, 3]`` float32 metres in the OpenCV camera frame (x right, y down,
    z forward); pixel indices are ``[P, 2]`` int (row, col).

The same code path serves deployment (``PoseEstimator.predict``) and the partial-depth training renderer, so the model
sees identical preprocessing in both.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .errors import (DepthDtypeError, DepthUnitError, EmptyDepthError, IntrinsicsError, InvalidPointsError,
                     RegionError, TooFewPointsError)
from .geometry import farthest_point_order

__all__ = ["CropResult", "PreparedPoints", "MIN_POINTS", "depth_to_metres", "check_intrinsics", "check_box",
           "check_mask", "crop_points", "prepare_points", "check_points", "statistical_outlier_mask",
           "organized_outlier_mask",
           "nearest_depth_cluster", "auto_masks", "fit_plane_ransac", "fps_order", "find_support_plane"]

MIN_POINTS = 64                 # fewer points than this after the crop cannot give a meaningful pose
PLAUSIBLE_DEPTH_M = (0.05, 30.0)  # median valid depth must fall in here for the declared unit to be believed


@dataclass
class CropResult:
    """Points of one object cropped from a depth frame.

    Attributes:
        points: [P, 3] float32 metres, camera frame.
        pixels: [P, 2] int64 (row, col) of each point in the depth frame.
        K: [3, 3] float64 intrinsics actually used (rescaled to the frame size if needed).
        diagnostics: counts after each stage (``region``, ``valid``, ``gated``, ``subsampled``, ``cluster``,
            ``inliers``) and the chosen ``cluster_depth_m`` (box crops) — for logging and debugging.
    """
    points: np.ndarray
    pixels: np.ndarray
    K: np.ndarray
    diagnostics: dict = field(default_factory=dict)

    def mask(self, shape) -> np.ndarray:
        """[H, W] bool mask of the surviving pixels."""
        m = np.zeros(shape, dtype=bool)
        m[self.pixels[:, 0], self.pixels[:, 1]] = True
        return m


@dataclass
class PreparedPoints:
    """Model input for one object and what maps the outputs back to metres.

    Attributes:
        model_points: [N, 3] float32 model units, FPS-ordered, centred: ``(p_m − centre_m) / scale``.
        centre_m: [3] float64 metres, camera frame (subtracted before scaling).
        scale: metres per model unit (from the model metadata).
        order: [N] int64 indices into the metric points that were passed in (FPS order; repeats when P < N).
    Map back: ``x_m = x_model · scale + centre_m`` (points and translations; rotations are unchanged).
    """
    model_points: np.ndarray
    centre_m: np.ndarray
    scale: float
    order: np.ndarray

    def to_metres(self, x_model: np.ndarray) -> np.ndarray:
        """[..., 3] model units → [..., 3] metres, camera frame."""
        return np.asarray(x_model, np.float64) * self.scale + self.centre_m


# ----------------------------------------------------------------------------------------------------------------------
# Validation

def _unit_scale(depth_unit) -> float:
    """metres per stored depth unit."""
    if isinstance(depth_unit, str):
        table = {"mm": 1e-3, "m": 1.0, "cm": 1e-2}
        if depth_unit not in table:
            raise DepthUnitError(f"depth_unit must be 'mm', 'm', 'cm' or metres per unit as a number, got {depth_unit!r}")
        return table[depth_unit]
    try:
        s = float(depth_unit)
    except (TypeError, ValueError):
        raise DepthUnitError(f"depth_unit must be 'mm', 'm', 'cm' or a positive number, got {depth_unit!r}") from None
    if not (math.isfinite(s) and s > 0):
        raise DepthUnitError(f"depth_unit as a number is metres per stored unit and must be positive, got {s}")
    return s


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
    d = np.multiply(depth, np.float32(scale), dtype=np.float32)                 # [H, W] metres
    if np.issubdtype(depth.dtype, np.unsignedinteger):                          # always finite and ≥ 0: 0 stays 0
        n_valid = int(np.count_nonzero(depth))
    else:
        valid = np.isfinite(d) & (d > 0)                                        # [H, W]
        d[~valid] = 0.0
        n_valid = int(np.count_nonzero(valid))
    if n_valid == 0:
        raise EmptyDepthError(f"depth frame {depth.shape} has no valid pixel (all 0, negative, NaN or Inf); "
                              "check that the camera delivers depth and the scene is within its range")
    if check_plausible:
        sub = d[::4, ::4]                                                       # unit check on a 1/16 lattice
        med = float(np.median(sub[sub > 0])) if (sub > 0).any() else float(np.median(d[valid]))
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


def check_intrinsics(K, depth_shape, image_size=None) -> np.ndarray:
    """Validate intrinsics against a frame and rescale them to it.

    Convention: ``K`` [3, 3] pinhole ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (skew allowed); ``depth_shape`` (H, W);
    ``image_size`` (W, H) that ``K`` belongs to, or None for "the frame's own size".
    Returns [3, 3] float64 K for the frame. Raises ``IntrinsicsError``.
    """
    try:
        K = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError):
        raise IntrinsicsError("K must be a numeric 3×3 matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]") from None
    if K.shape != (3, 3):
        raise IntrinsicsError(f"K must be 3×3 [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got shape {K.shape}"
                              + (" (pass np.array(K).reshape(3, 3) for a flat list of 9)" if K.size == 9 else ""))
    if not np.all(np.isfinite(K)):
        raise IntrinsicsError("K contains NaN or Inf")
    if not (K[0, 0] > 0 and K[1, 1] > 0) or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
        raise IntrinsicsError(f"K is not a pinhole matrix (need fx, fy > 0 and last row 0 0 1): {K.tolist()}")
    H, W = int(depth_shape[0]), int(depth_shape[1])
    K = K.copy()
    if image_size is not None:
        try:
            w0, h0 = (int(v) for v in image_size)
        except (TypeError, ValueError):
            raise IntrinsicsError(f"image_size must be (width, height), got {image_size!r}") from None
        if w0 <= 0 or h0 <= 0:
            raise IntrinsicsError(f"image_size must be positive (width, height), got {image_size!r}")
        if (w0, h0) != (W, H):
            sx, sy = W / w0, H / h0
            if abs(sx - sy) > 0.01 * max(sx, sy):
                raise IntrinsicsError(
                    f"K belongs to a {w0}×{h0} image but the depth frame is {W}×{H} (different aspect ratio); a crop "
                    "cannot be undone from the size alone — pass the intrinsics of the depth frame itself")
            # pixel centres at integer coordinates: x' = (x + 0.5) · s − 0.5
            K[0, 0] *= sx; K[0, 1] *= sx; K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
            K[1, 1] *= sy; K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    if not (0 < K[0, 2] < W - 1 and 0 < K[1, 2] < H - 1):
        raise IntrinsicsError(
            f"principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) lies outside the {W}×{H} depth frame: K does not match the "
            "image size. Pass image_size=(W, H) of the image K was calibrated for, or the intrinsics of this frame")
    return K


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


def check_mask(mask, shape) -> np.ndarray:
    """Validate a mask for a frame of ``shape`` (H, W). Returns [H, W] bool. Raises ``RegionError``."""
    m = np.asarray(mask)
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
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InvalidPointsError(f"{name} must be a numeric [P, 3] array") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidPointsError(f"{name} must be [P, 3] (x, y, z rows), got shape {p.shape}")
    bad = ~np.all(np.isfinite(p), axis=1)                                       # [P]
    if bad.any():
        raise InvalidPointsError(f"{name} contain {int(bad.sum())} row(s) with NaN/Inf (first at index "
                                 f"{int(np.argmax(bad))}); drop invalid points first, e.g. p[np.isfinite(p).all(1)]")
    return p


# ----------------------------------------------------------------------------------------------------------------------
# Cleaning

def statistical_outlier_mask(points: np.ndarray, k: int = 8, std_ratio: float = 2.0) -> np.ndarray:
    """PCL-style statistical outlier removal.

    Convention: ``points`` [P, 3] metres. A point is an inlier when its mean distance to its ``k`` nearest neighbours
    is at most mean + ``std_ratio`` · std of that statistic over all points. Returns [P] bool inliers.
    """
    P = len(points)
    if P <= k + 1:
        return np.ones(P, dtype=bool)
    tree = cKDTree(points)
    d, _ = tree.query(points, k=k + 1)                                          # [P, k+1], column 0 = self
    mean_d = d[:, 1:].mean(axis=1)                                              # [P]
    thr = mean_d.mean() + std_ratio * mean_d.std()
    return mean_d <= thr


def organized_outlier_mask(points: np.ndarray, rows: np.ndarray, cols: np.ndarray, step: int = 1,
                           std_ratio: float = 2.0) -> np.ndarray:
    """Statistical outlier removal on the pixel grid (organized clouds): neighbours are the 8 adjacent grid cells.

    Convention: ``points`` [P, 3] metres, back-projected from pixels (``rows``, ``cols``) [P] that lie on a regular
    grid of pitch ``step`` (the crop's subsampling). For each point the mean distance to its present grid neighbours
    is compared with mean + ``std_ratio`` · std of that statistic over all points; points with no neighbour at all
    are outliers (isolated flying pixels). Same criterion as ``statistical_outlier_mask`` but the neighbourhood
    comes from the image instead of a k-d tree, as 8 whole-grid shifts (7–15× faster than the tree on a crop).
    Returns [P] bool inliers.
    """
    P = len(points)
    if P < 10:
        return np.ones(P, dtype=bool)
    r = (rows - rows.min()) // step                                             # [P] grid coordinates
    c = (cols - cols.min()) // step
    h, w = int(r.max()) + 1, int(c.max()) + 1
    grid = np.full((3, h + 2, w + 2), np.nan, np.float32)                       # [3, h+2, w+2], 1-cell NaN border
    grid[:, r + 1, c + 1] = np.asarray(points, np.float32).T
    core = grid[:, 1:-1, 1:-1]                                                  # [3, h, w] every cell
    total = np.zeros((h, w), np.float32)                                        # [h, w] sum of neighbour distances
    count = np.zeros((h, w), np.float32)                                        # [h, w] present neighbours
    for dr in (-1, 0, 1):                                                       # whole-grid shifts, one per direction
        for dc in (-1, 0, 1):
            if dr == 0 and dc == 0:
                continue
            diff = grid[:, 1 + dr:h + 1 + dr, 1 + dc:w + 1 + dc] - core         # [3, h, w] (NaN = absent)
            dist = np.sqrt(np.einsum("kij,kij->ij", diff, diff))                # [h, w]
            ok = np.isfinite(dist)
            total += np.where(ok, dist, np.float32(0.0))
            count += ok
    total, count = total[r, c], count[r, c]                                     # [P] at the points' cells
    has = count > 0
    if has.sum() < 10:
        return has
    mean_d = (total[has] / count[has]).astype(np.float64)                       # [P']
    thr = mean_d.mean() + std_ratio * mean_d.std()
    keep = np.zeros(P, dtype=bool)
    keep[has] = mean_d <= thr
    return keep


def nearest_depth_cluster(z: np.ndarray, gap_m: float = 0.03, rel_gap: float = 0.03,
                          min_fraction: float = 0.1) -> np.ndarray:
    """Keep the nearest depth cluster that is big enough (background rejection inside a box).

    Convention: ``z`` [P] metres. Sorted depths are split wherever consecutive values differ by more than
    max(``gap_m``, ``rel_gap`` · z); the nearest cluster holding at least ``min_fraction`` of the points wins.
    Returns [P] bool.
    """
    P = len(z)
    if P == 0:
        return np.zeros(0, dtype=bool)
    order = np.argsort(z, kind="stable")                                        # [P]
    zs = z[order]                                                               # [P] sorted
    gaps = np.diff(zs) > np.maximum(gap_m, rel_gap * zs[:-1])                   # [P-1]
    labels_sorted = np.concatenate([[0], np.cumsum(gaps)])                      # [P] cluster id, nearest = 0
    counts = np.bincount(labels_sorted)                                         # [C]
    big = np.nonzero(counts >= max(1, min_fraction * P))[0]
    chosen = int(big[0]) if len(big) else int(np.argmax(counts))
    keep = np.zeros(P, dtype=bool)
    keep[order[labels_sorted == chosen]] = True
    return keep


# ----------------------------------------------------------------------------------------------------------------------
# Crop

def crop_points(depth, K, *, box=None, mask=None, depth_unit="mm", image_size=None, min_depth: float = 0.1,
                max_depth: float = 10.0, max_points: int = 4096, reject_background: bool | None = None,
                outlier_k: int = 8, outlier_std: float = 2.0, min_points: int = MIN_POINTS,
                check_plausible: bool = True, remove_support_plane: bool | None = None, support_plane=None,
                plane_height: float = 0.012, prevalidated: bool = False) -> CropResult:
    """Depth frame + box/mask → cleaned object points in metres.

    Convention: ``depth`` [H, W] in ``depth_unit``; ``K`` [3, 3] for ``image_size`` (W, H) or the frame itself;
    ``box`` (x, y, w, h) pixels and/or ``mask`` [H, W] bool (both → their intersection; neither → whole frame).
    Returns ``CropResult`` with points [P, 3] float32 metres in the camera frame.

    Stages: validation → region → invalid-depth removal → depth gating [``min_depth``, ``max_depth``] m → support
    plane removal (points less than ``plane_height`` above the frame's dominant plane, or beyond it, are dropped;
    ``support_plane`` = precomputed (normal, offset) from ``find_support_plane``; default on for a box without a
    mask, and skipped when the frame has no dominant plane or too few points would remain) → regular pixel-grid
    subsampling to at most ``max_points`` → background rejection (nearest depth cluster; default on for a box
    without a mask) → statistical outlier removal (``outlier_std``; 0 disables): on the pixel grid with its 8
    neighbours (``organized_outlier_mask``) for the default ``outlier_k`` = 8, else k-d tree with k = ``outlier_k``.
    Raises ``DepthDtypeError``, ``DepthUnitError``, ``EmptyDepthError``, ``IntrinsicsError``, ``RegionError``,
    ``TooFewPointsError``. ``check_plausible=False`` skips the unit plausibility check (already-validated frames);
    ``prevalidated=True`` takes ``depth`` as the float32 metres that ``depth_to_metres`` returned for this frame and
    skips conversion and validation altogether (``PoseEstimator`` validates each frame once for all its objects).
    """
    if prevalidated:
        d = depth                                                               # [H, W] float32 m, 0 = invalid
        if not (isinstance(d, np.ndarray) and d.dtype == np.float32 and d.ndim == 2):
            raise DepthDtypeError("prevalidated=True needs the [H, W] float32 metres from depth_to_metres, got "
                                  f"{getattr(d, 'dtype', type(d))} {getattr(d, 'shape', '')}")
    else:
        d = depth_to_metres(depth, depth_unit, check_plausible=check_plausible) # [H, W] float32 m
    H, W = d.shape
    Kf = check_intrinsics(K, (H, W), image_size)                                # [3, 3]
    y0, x0, y1, x1 = 0, 0, H, W
    if box is not None:
        x0, y0, x1, y1 = check_box(box, (H, W))
    win = d[y0:y1, x0:x1]                                                       # [h, w] the box window (a view)
    region = np.ones(win.shape, dtype=bool)                                     # [h, w]
    if mask is not None:
        region &= check_mask(mask, (H, W))[y0:y1, x0:x1]
        if not region.any():
            raise RegionError("the mask and the box do not overlap; pass a box that contains the mask")
    diag = {"region": int(region.sum())}
    valid = region & (win > 0)                                                  # [h, w]
    diag["valid"] = int(valid.sum())
    if diag["valid"] == 0:
        raise EmptyDepthError(f"no valid depth inside the region ({diag['region']} pixels); the object may be too close, "
                              "too far, or too dark/shiny for the depth camera — check the box/mask and the depth frame")
    valid &= (win >= min_depth) & (win <= max_depth)
    diag["gated"] = int(valid.sum())
    if diag["gated"] < min_points:
        raise TooFewPointsError(f"{diag['gated']} valid pixels within {min_depth}–{max_depth} m in the region (need "
                                f"≥ {min_points}); enlarge the box/mask or change min_depth/max_depth")
    if remove_support_plane is None:
        remove_support_plane = box is not None and mask is None
    if remove_support_plane:
        plane = support_plane if support_plane is not None else find_support_plane(d, Kf)
        if plane is not None:
            n, off = plane
            # height above the plane of every window pixel: z · (n · ray(row, col)) + off, the ray term separable
            cx = (np.arange(x0, x1, dtype=np.float32) - Kf[0, 2]) / Kf[0, 0] * n[0]     # [w]
            ry = (np.arange(y0, y1, dtype=np.float32) - Kf[1, 2]) / Kf[1, 1] * n[1] + n[2]  # [h]
            h = win * (ry[:, None] + cx[None, :]).astype(np.float32) + np.float32(off)  # [h, w] m
            above = valid & (h > plane_height)                                  # [h, w]
            n_above = int(np.count_nonzero(above))
            if n_above >= min_points:
                valid = above
                diag["above_plane"] = n_above
    s = 1                                                                       # grid pitch of the kept pixels
    n_valid = int(np.count_nonzero(valid))
    if n_valid > max_points:                                                    # regular grid, deterministic
        s = int(math.ceil(math.sqrt(n_valid / max_points)))
        if np.count_nonzero(valid[::s, ::s]) < min_points:                      # pathological sparse layouts
            rows, cols = np.nonzero(valid)
            keep = np.zeros(len(rows), bool); keep[:: int(math.ceil(len(rows) / max_points))] = True
            rows, cols = rows[keep], cols[keep]
            s = 0                                                               # not a grid any more
        else:
            rows, cols = np.nonzero(valid[::s, ::s])                            # [P] on the lattice
            rows, cols = rows * s, cols * s
    else:
        rows, cols = np.nonzero(valid)                                          # [P], [P] in the window
    rows, cols = rows + y0, cols + x0                                           # frame pixels
    diag["subsampled"] = int(len(rows))
    z = d[rows, cols].astype(np.float64)                                        # [P]
    x = (cols - Kf[0, 2] - Kf[0, 1] * (rows - Kf[1, 2]) / Kf[1, 1]) * z / Kf[0, 0]
    y = (rows - Kf[1, 2]) * z / Kf[1, 1]
    pts = np.stack([x, y, z], axis=1)                                           # [P, 3] m
    if reject_background is None:
        reject_background = box is not None and mask is None
    if reject_background:
        keep = nearest_depth_cluster(z)                                         # [P]
        pts, rows, cols = pts[keep], rows[keep], cols[keep]
        diag["cluster"] = int(keep.sum())
        diag["cluster_depth_m"] = float(np.median(pts[:, 2]))
    if outlier_std and outlier_std > 0:
        if s and outlier_k == 8:                                                # organized: the 8 grid neighbours
            keep = organized_outlier_mask(pts, rows - y0, cols - x0, step=s, std_ratio=outlier_std)  # [P]
        else:
            keep = statistical_outlier_mask(pts, k=outlier_k, std_ratio=outlier_std)  # [P]
        pts, rows, cols = pts[keep], rows[keep], cols[keep]
    diag["inliers"] = int(len(pts))
    if len(pts) < min_points:
        raise TooFewPointsError(f"only {len(pts)} points survived the crop (need ≥ {min_points}; stages: {diag}); "
                                "enlarge the box/mask, move the camera closer, or check the depth frame")
    return CropResult(points=pts.astype(np.float32), pixels=np.stack([rows, cols], 1).astype(np.int64), K=Kf,
                      diagnostics=diag)


def find_support_plane(depth_m: np.ndarray, K: np.ndarray, *, threshold: float = 0.012, min_fraction: float = 0.2,
                       grid: int = 8, seed: int = 0):
    """The frame's dominant plane (table, floor) if it is dominant enough, else None.

    Convention: ``depth_m`` [H, W] float metres (0 = invalid), ``K`` [3, 3] for this frame. RANSAC on a ``grid``-pixel
    lattice; the plane counts when at least ``min_fraction`` of the lattice's valid points are within ``threshold``.
    Returns (normal [3], offset) oriented so the camera side is positive (see ``fit_plane_ransac``), or None.
    """
    sub = np.asarray(depth_m)[::grid, ::grid]                                   # [h, w] m
    r, c = np.nonzero(sub > 0)
    if len(r) < 100:
        return None
    z = sub[r, c].astype(np.float64)
    rows, cols = r * grid, c * grid
    pts = np.stack([(cols - K[0, 2]) * z / K[0, 0], (rows - K[1, 2]) * z / K[1, 1], z], 1)  # [S, 3] m
    n, off, inl = fit_plane_ransac(pts, threshold=threshold, seed=seed)
    return (n, off) if inl.mean() >= min_fraction else None


# ----------------------------------------------------------------------------------------------------------------------
# Model input

def fps_order(points: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """``geometry.farthest_point_order`` with the SDK's typed error. Convention: [P, 3] → indices [n] (nested)."""
    if len(points) == 0:
        raise TooFewPointsError("farthest-point ordering got no points")
    return farthest_point_order(points, n, start=start)


def prepare_points(points_m, num_points: int, scale: float, *, min_points: int = MIN_POINTS,
                   max_fps_input: int = 4096) -> PreparedPoints:
    """Metric object points → the model's FPS-ordered, centred, scaled input.

    Convention: ``points_m`` [P, 3] metres (camera frame). Output ``model_points`` [N, 3] float32 model units,
    ``(p − centre) / scale`` with ``centre`` the centroid in metres; FPS-ordered (nested prefixes, as the model's
    in-graph downsampling expects), starting from the point farthest from the centroid. When P > ``max_fps_input`` the
    points are first thinned with a regular stride (deterministic). When P < N the FPS order repeats (wraps).
    Raises ``InvalidPointsError`` (shape, NaN/Inf), ``TooFewPointsError`` (P < ``min_points``).
    """
    p = check_points(points_m)                                                  # [P, 3] float64 m
    if not (isinstance(num_points, (int, np.integer)) and num_points > 0):
        raise InvalidPointsError(f"num_points must be a positive int, got {num_points!r}")
    if not (math.isfinite(float(scale)) and float(scale) > 0):
        raise InvalidPointsError(f"scale must be positive (metres per model unit), got {scale!r}")
    P = len(p)
    if P < min_points:
        raise TooFewPointsError(f"{P} points given, need at least {min_points}; enlarge the crop")
    base = np.arange(P)
    if P > max_fps_input:
        base = base[:: int(math.ceil(P / max_fps_input))]                       # [P'] regular thinning
    q = p[base]                                                                 # [P', 3]
    centre = q.mean(axis=0)                                                     # [3] m
    qc = ((q - centre) / float(scale)).astype(np.float32)                       # [P', 3] model units
    start = int(np.argmax(np.einsum("ij,ij->i", qc, qc)))
    idx = fps_order(qc, int(num_points), start=start)                          # [N]
    return PreparedPoints(model_points=np.ascontiguousarray(qc[idx]), centre_m=centre, scale=float(scale),
                          order=base[idx])


# ----------------------------------------------------------------------------------------------------------------------
# Auto crop: tabletop segmentation for users without a detector

def fit_plane_ransac(points: np.ndarray, threshold: float = 0.01, iterations: int = 200, seed: int = 0,
                     confidence: float = 0.999, chunk: int = 32):
    """RANSAC plane fit with a least-squares refit on the inliers.

    Adaptive: hypotheses are scored ``chunk`` at a time, stopping (before ``iterations``) once the best inlier
    fraction w makes a better, missed plane unlikely: tried ≥ log(1 − ``confidence``) / log(1 − w³).

    Convention: ``points`` [P, 3] metres. Returns (normal [3] unit, offset d, inliers [P] bool) with
    ``n · x + d = 0`` on the plane, oriented so the camera origin has positive signed distance (d > 0): objects
    standing on the plane, seen from the camera, have ``n · x + d > 0``.
    """
    P = len(points)
    if P < 3:
        raise TooFewPointsError(f"plane fit needs ≥ 3 points, got {P}")
    rng = np.random.default_rng(seed)
    best_n, best_d, best_count = None, 0.0, -1
    tri = rng.integers(0, P, size=(iterations, 3))                              # [I, 3]
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]           # [I, 3] each
    normals = np.cross(b - a, c - a)                                            # [I, 3]
    norms = np.linalg.norm(normals, axis=1)                                     # [I]
    ok = norms > 1e-9
    normals, a = normals[ok] / norms[ok, None], a[ok]
    offsets = -np.einsum("ij,ij->i", normals, a)                                # [I']
    if len(normals) == 0:
        raise TooFewPointsError("plane fit failed: all sampled point triples are collinear")
    sub = points[:: max(1, P // 1500)].astype(np.float32)                       # [S ≤ 3000, 3] scoring subset
    sx, sy, sz = sub[:, :1], sub[:, 1:2], sub[:, 2:]                            # [S, 1] each
    nf, of = normals.astype(np.float32), offsets.astype(np.float32)             # [I', 3], [I']
    best_count, j, done = -1, 0, 0
    for lo in range(0, len(nf), chunk):                                         # adaptive RANSAC: score in chunks,
        n_c, o_c = nf[lo:lo + chunk], of[lo:lo + chunk]                         # stop once more hypotheses cannot
        # signed distances by broadcasting, not a K=3 BLAS matmul (several times slower, worse on a loaded CPU)
        dist = o_c + sx * n_c[:, 0] + sy * n_c[:, 1] + sz * n_c[:, 2]          # [S, c]
        counts = np.count_nonzero(np.abs(dist) < threshold, axis=0)             # [c]
        k = int(np.argmax(counts))
        if counts[k] > best_count:
            best_count, j = int(counts[k]), lo + k
        done = lo + len(n_c)
        w = best_count / len(sub)                                               # inlier fraction of the best so far
        if w >= 1 or done >= math.log(1 - confidence) / math.log(max(1e-12, 1 - w ** 3)):
            break                                                               # P(missed better plane) < 1 − conf.
    best_n, best_d = normals[j], offsets[j]
    for _ in range(2):                                                          # least-squares refinement
        inl = np.abs(points @ best_n + best_d) < threshold                      # [P]
        if inl.sum() < 3:
            break
        q = points[inl]
        c0 = q.mean(0)
        qc = q - c0                                                             # [P', 3]
        _, vecs = np.linalg.eigh(qc.T @ qc)                                     # 3×3 scatter, ascending eigenvalues
        best_n = vecs[:, 0]                                                     # least-variance direction
        best_d = -float(best_n @ c0)
    if best_d < 0:
        best_n, best_d = -best_n, -best_d
    inl = np.abs(points @ best_n + best_d) < threshold
    return best_n, float(best_d), inl


def auto_masks(depth, K, *, depth_unit="mm", image_size=None, min_depth: float = 0.1, max_depth: float = 3.0,
               plane_threshold: float = 0.012, min_height: float = 0.015, max_height: float = 0.5,
               cluster_radius: float = 0.02, min_cluster_points: int = 500, max_objects: int = 10,
               stride: int | None = None, table_hull: bool = True, merge_overlap: float = 0.5,
               seed: int = 0) -> list:
    """Tabletop auto-crop: dominant plane (RANSAC) + Euclidean clustering of what stands on it → object masks.

    Convention: ``depth`` [H, W] in ``depth_unit``; ``K`` [3, 3]. Returns a list of [H, W] bool masks, largest object
    first (possibly empty if nothing stands on the plane). The plane is fitted on ≤ 20k valid pixels; points between
    ``min_height`` and ``max_height`` above it are clustered (neighbours within ``cluster_radius`` m) on a pixel grid
    of ``stride`` (default: the stride whose spacing at the median depth is about ``cluster_radius`` / 2); every
    full-resolution pixel above the plane then joins the cluster of its nearest grid point (within
    ``cluster_radius``). With ``table_hull`` only points whose projection onto the plane falls inside the convex hull
    of the table inliers are kept (PCL's polygonal-prism idea: background beyond the table is ignored). Clusters
    touching the image border or smaller than ``min_cluster_points`` full-resolution pixels are dropped.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    d = depth_to_metres(depth, depth_unit)                                      # [H, W] m
    H, W = d.shape
    Kf = check_intrinsics(K, (H, W), image_size)
    valid = (d >= min_depth) & (d <= max_depth)                                 # [H, W]
    rows, cols = np.nonzero(valid)                                              # [P]
    if len(rows) < 3 * min_cluster_points:
        raise EmptyDepthError(f"only {len(rows)} valid pixels within {min_depth}–{max_depth} m; auto crop needs a "
                              "table and objects in view")
    z = d[rows, cols]                                                           # [P] float32
    x = (cols.astype(np.float32) - np.float32(Kf[0, 2])) * z / np.float32(Kf[0, 0])
    y = (rows.astype(np.float32) - np.float32(Kf[1, 2])) * z / np.float32(Kf[1, 1])
    step = max(1, len(z) // 20000)
    sub = np.stack([x[::step], y[::step], z[::step]], 1).astype(np.float64)     # [≤20k, 3] for the plane fit
    n, off, inl = fit_plane_ransac(sub, threshold=plane_threshold, seed=seed)
    h = x * np.float32(n[0]) + y * np.float32(n[1]) + z * np.float32(n[2]) + np.float32(off)  # [P] height
    above = (h > min_height) & (h < max_height)                                 # [P]
    if table_hull and inl.sum() >= 3:
        from scipy.spatial import ConvexHull, QhullError
        e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)                                                    # (e1, e2) span the plane
        table2d = sub[inl] @ np.stack([e1, e2], 1)                              # [T, 2]
        try:
            eq = ConvexHull(table2d).equations                                  # [F, 3]: inside ⇔ a·q + b ≤ 0
            idx = np.nonzero(above)[0]
            q2d = np.stack([x[idx], y[idx], z[idx]], 1).astype(np.float64) @ np.stack([e1, e2], 1)  # [Q, 2]
            outside = np.any(q2d @ eq[:, :2].T + eq[:, 2] > 1e-9, axis=1)       # [Q]
            above[idx[outside]] = False                                         # outside the table's outline
        except QhullError:                                                      # degenerate (collinear) table
            pass
    rows, cols = rows[above], cols[above]
    pts = np.stack([x[above], y[above], z[above]], 1)                           # [Q, 3] m
    if len(rows) < min_cluster_points:
        return []
    if stride is None:
        stride = int(np.clip(round(Kf[0, 0] * cluster_radius / 2 / float(np.median(pts[:, 2]))), 1, 16))
    grid = (rows % stride == 0) & (cols % stride == 0)                          # [Q] subsample for clustering
    sp = pts[grid]                                                              # [S, 3]
    if len(sp) < 2:
        return []
    tree = cKDTree(sp)
    pairs = tree.query_pairs(cluster_radius, output_type="ndarray")             # [E, 2]
    S = len(sp)
    adj = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(S, S))
    _, lab_sub = connected_components(adj, directed=False)                      # [S]
    dist, nn = tree.query(pts, k=1, distance_upper_bound=cluster_radius)        # [Q]
    ok = np.isfinite(dist)
    labels = np.full(len(pts), -1, dtype=np.int64)                              # [Q]
    labels[ok] = lab_sub[nn[ok]]
    # hollow objects (cups, bowls) split into rim/inside and outside clusters: merge a cluster into a bigger one when
    # more than ``merge_overlap`` of its pixel bounding box lies inside the bigger one's box
    labs, counts = np.unique(labels[labels >= 0], return_counts=True)
    by_label = np.argsort(labels, kind="stable")                                # points grouped by label
    starts = np.searchsorted(labels[by_label], labs)                            # [C] first index of each label
    order = [k for k in np.argsort(-counts, kind="stable") if counts[k] >= min_cluster_points // 10]  # skip specks
    groups = []                                                                 # [[bbox r0, c0, r1, c1], [labels]]
    for k in order:
        sel = by_label[starts[k]:starts[k] + counts[k]]                         # indices of cluster k
        r, c = rows[sel], cols[sel]
        box = np.array([r.min(), c.min(), r.max() + 1, c.max() + 1])
        area = (box[2] - box[0]) * (box[3] - box[1])
        for g in groups:
            gb = g[0]
            inter = max(0, min(box[2], gb[2]) - max(box[0], gb[0])) * max(0, min(box[3], gb[3]) - max(box[1], gb[1]))
            if inter > merge_overlap * area:
                g[0] = np.array([min(box[0], gb[0]), min(box[1], gb[1]), max(box[2], gb[2]), max(box[3], gb[3])])
                g[1].append(labs[k])
                break
        else:
            groups.append([box, [labs[k]]])
    masks = []
    for box, members in groups:
        sel = np.isin(labels, members)
        if sel.sum() < min_cluster_points:
            continue
        if box[0] == 0 or box[1] == 0 or box[2] == H or box[3] == W:
            continue                                                            # cut by the image border
        m = np.zeros((H, W), dtype=bool)
        m[rows[sel], cols[sel]] = True
        masks.append(m)
    masks.sort(key=lambda m: -int(m.sum()))
    return masks[:max_objects]
