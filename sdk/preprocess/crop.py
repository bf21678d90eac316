"""Depth frame + box/mask → cleaned object points (region, depth gating, object-cluster pick, outlier removal).

Convention:
    ``depth`` [H, W] in a declared unit, ``K`` [3, 3], boxes ``(x, y, w, h)`` pixels, masks [H, W] bool (see
    ``equipose.preprocess.validate``). Points are ``[P, 3]`` float32 metres in the OpenCV camera frame (x right,
    y down, z forward); pixel indices are ``[P, 2]`` int (row, col). The same code path serves deployment
    (``PoseEstimator.predict``) and the partial-depth training renderer, so the model sees identical preprocessing.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from equipose.core.errors import ConfigError, DepthDtypeError, EmptyDepthError, RegionError, TooFewPointsError
from equipose.core.order_statistics import median
from equipose.preprocess.base import base_mask, facing_cosines
from equipose.preprocess.plane import find_support_plane, plane_height_terms
from equipose.preprocess.sampling import MIN_POINTS
from equipose.preprocess.surfaces import (box_object_cluster, continues_beyond_box, nearest_depth_cluster,
                                         surface_segments)
from equipose.preprocess.validate import check_box, check_intrinsics, check_mask, depth_to_metres

__all__ = ["CropResult", "check_crop_options", "crop_points", "statistical_outlier_mask", "organized_outlier_mask",
           "PLANE_HEIGHT_RANGE", "PLANE_NOISE_SIGMAS"]

PLANE_HEIGHT_RANGE = (0.006, 0.012)   # m: plane_height="auto" keeps PLANE_NOISE_SIGMAS × the table's depth noise in it
PLANE_NOISE_SIGMAS = 3.5              # (Kinect-class noise, σ ≈ 2 mm: 8 mm; stereo noise of 3.5 mm and more: 12 mm)


@dataclass
class CropResult:
    """Points of one object cropped from a depth frame.

    Attributes:
        points: [P, 3] float32 metres, camera frame.
        pixels: [P, 2] int64 (row, col) of each point in the depth frame.
        K: [3, 3] float64 intrinsics actually used (rescaled to the frame size if needed).
        diagnostics: counts after each stage (``region``, ``valid``, ``gated``, ``subsampled``, ``cluster``,
            ``inliers``), and for box crops the chosen ``cluster_depth_m``, the number of depth ``clusters`` large
            enough to be the object and ``occluded_fraction`` (the share of the object's view taken by nearer
            clusters, dropped); with the support plane removed, ``base_points``: the object's base given back from
            the plane band (counted in ``inliers``).
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
    comes from the image instead of a k-d tree (one compiled pass over the grid cells).
    Returns [P] bool inliers.
    """
    P = len(points)
    if P < 10:
        return np.ones(P, dtype=bool)
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    r = (rows - rows.min()) // step                                             # [P] grid coordinates
    c = (cols - cols.min()) // step
    return _grid_inliers(np.ascontiguousarray(points, np.float32), r, c, float(std_ratio))


@njit(cache=True)
def _grid_inliers(points, r, c, std_ratio):
    """[P] bool: the points [P, 3] float32 at grid cells (``r``, ``c``) [P] whose mean distance to their present grid
    neighbours is at most mean + ``std_ratio`` · std of that statistic; points without neighbours are out."""
    total, count = _grid_neighbour_distances(points, r, c)                      # [P], [P]
    P = len(points)
    mean_d = np.zeros(P)                                                        # [P] float64, valid where count > 0
    n = 0
    for i in range(P):
        if count[i] > 0:
            mean_d[i] = np.float64(total[i] / count[i])
            n += 1
    if n < 10:
        return count > 0
    mu, var = mean_d.sum() / n, 0.0
    for i in range(P):
        if count[i] > 0:
            var += (mean_d[i] - mu) ** 2
    thr = mu + std_ratio * np.sqrt(var / n)
    keep = np.zeros(P, np.bool_)
    for i in range(P):
        keep[i] = count[i] > 0 and mean_d[i] <= thr
    return keep


@njit(cache=True)
def _grid_neighbour_distances(points, r, c) -> tuple:
    """(sum of float32 distances to the present 8 grid neighbours [P], their count [P]) of points [P, 3] float32 at
    grid cells (``r``, ``c``) [P]."""
    P = len(points)
    h, w = r.max() + 1, c.max() + 1
    cell = np.full((h + 2, w + 2), -1, np.int64)                                # 1-cell border of absent cells
    for i in range(P):
        cell[r[i] + 1, c[i] + 1] = i
    total, count = np.zeros(P, np.float32), np.zeros(P, np.float32)
    for i in range(P):
        for dr in range(-1, 2):
            for dc in range(-1, 2):
                j = cell[r[i] + 1 + dr, c[i] + 1 + dc]
                if (dr == 0 and dc == 0) or j < 0:
                    continue
                dx, dy, dz = points[j, 0] - points[i, 0], points[j, 1] - points[i, 1], points[j, 2] - points[i, 2]
                total[i] += np.sqrt(dx * dx + dy * dy + dz * dz)
                count[i] += 1
    return total, count


@njit(cache=True)
def _window_mask(win, region, min_depth, max_depth) -> tuple:
    """One pass over the box window ``win`` [h, w] float32 metres (0 = invalid) within ``region`` [h, w] bool (None:
    all of it). Returns (gated [h, w] bool: valid and within [``min_depth``, ``max_depth``] (float32), counts [3]:
    region, valid, gated pixels)."""
    h, w = win.shape
    gated = np.zeros((h, w), np.bool_)
    counts = np.zeros(3, np.int64)
    for r in range(h):
        for c in range(w):
            if region is not None and not region[r, c]:
                continue
            counts[0] += 1
            v = win[r, c]
            if not v > 0:
                continue
            counts[1] += 1
            if min_depth <= v <= max_depth:
                gated[r, c] = True
                counts[2] += 1
    return gated, counts


@njit(cache=True)
def _split_at_plane(win, valid, ry, cx, off, plane_height) -> tuple:
    """(above [h, w] bool: the ``valid`` window pixels higher than ``plane_height`` above the plane whose heights
    ``plane_height_terms`` separates (ry [h], cx [w], off), computed in float32; their count; band [h, w] bool: the
    other ``valid`` pixels higher than −``plane_height``, the band the plane removal takes away)."""
    h, w = win.shape
    above = np.zeros((h, w), np.bool_)
    band = np.zeros((h, w), np.bool_)
    n = 0
    for r in range(h):
        for c in range(w):
            if valid[r, c]:
                z = win[r, c] * np.float32(ry[r] + cx[c]) + off
                if z > plane_height:
                    above[r, c] = True
                    n += 1
                elif z > -plane_height:
                    band[r, c] = True
    return above, n, band


@njit(cache=True)
def _near_plane_heights(win, valid, ry, cx, off, limit) -> np.ndarray:
    """[Q] float32 heights (m) of the ``valid`` window pixels within ``limit`` of the plane (``plane_height_terms``'s
    separable terms): the table around the object, where its depth noise shows."""
    h, w = win.shape
    out = np.empty(h * w, np.float32)
    n = 0
    for r in range(h):
        for c in range(w):
            if valid[r, c]:
                z = win[r, c] * np.float32(ry[r] + cx[c]) + off
                if -limit < z < limit:
                    out[n] = z
                    n += 1
    return out[:n]


def auto_plane_height(heights) -> float:
    """``plane_height`` (m) for the table pixels' ``heights`` [Q] m above the plane: ``PLANE_NOISE_SIGMAS`` × their
    robust standard deviation (1.4826 · MAD), within ``PLANE_HEIGHT_RANGE`` (its top without enough pixels)."""
    h = np.asarray(heights, np.float64)
    if len(h) < 50:
        return PLANE_HEIGHT_RANGE[1]
    sigma = 1.4826 * median(np.abs(h - median(h)))
    return float(np.clip(PLANE_NOISE_SIGMAS * sigma, *PLANE_HEIGHT_RANGE))


@njit(cache=True)
def _lattice_pixels(valid, s, y0, x0) -> tuple:
    """(rows [P], cols [P]) int64 frame pixels of the ``valid`` [h, w] window pixels on the frame's lattice of pitch
    ``s`` (frame rows and columns that are multiples of ``s``), row-major; the window starts at frame pixel (``y0``,
    ``x0``). The lattice belongs to the frame, not to the window: two regions over the same object (a box and the
    object's mask, or a detector's box from one frame to the next) sample the same pixels wherever they overlap."""
    h, w = valid.shape
    r0, c0 = (-y0) % s, (-x0) % s                                               # first window row / column on it
    n = 0
    for r in range(r0, h, s):
        for c in range(c0, w, s):
            n += valid[r, c]
    rows, cols = np.empty(n, np.int64), np.empty(n, np.int64)
    k = 0
    for r in range(r0, h, s):
        for c in range(c0, w, s):
            if valid[r, c]:
                rows[k], cols[k] = r + y0, c + x0
                k += 1
    return rows, cols


@njit(cache=True)
def _backproject(d, rows, cols, K):
    """[P, 3] float64 metres: the pixels (``rows``, ``cols``) [P] of the depth frame ``d`` [H, W] metres through the
    pinhole ``K`` [3, 3] (with skew)."""
    pts = np.empty((len(rows), 3))
    for p in range(len(rows)):
        z = np.float64(d[rows[p], cols[p]])
        r, c = rows[p], cols[p]
        pts[p, 0] = (c - K[0, 2] - K[0, 1] * (r - K[1, 2]) / K[1, 1]) * z / K[0, 0]
        pts[p, 1] = (r - K[1, 2]) * z / K[1, 1]
        pts[p, 2] = z
    return pts


# ----------------------------------------------------------------------------------------------------------------------
# Crop

_NUMBER_OPTIONS = {  # option: (lowest allowed, integer?)
    "min_depth": (0.0, False), "max_depth": (0.0, False), "max_points": (MIN_POINTS, True), "outlier_k": (1, True),
    "outlier_std": (0.0, False), "min_points": (1, True), "plane_height": (0.0, False)}
_FLAG_OPTIONS = ("reject_background", "check_plausible", "remove_support_plane", "keep_base", "prevalidated")


def check_crop_options(options: dict) -> dict:
    """Validate ``crop_points`` options given as a dict (``PoseEstimator(crop_options=...)``, ``predict(**options)``).

    Returns a copy. Raises ``ConfigError`` for unknown names, wrong types or out-of-range values.
    """
    if not isinstance(options, dict):
        raise ConfigError(f"crop options must be a dict of crop_points options, got {type(options).__name__}")
    known = set(_NUMBER_OPTIONS) | set(_FLAG_OPTIONS) | {"support_plane"}
    unknown = sorted(set(options) - known)
    if unknown:
        raise ConfigError(f"unknown crop option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    for k, v in options.items():
        if k == "plane_height" and isinstance(v, str):
            if v != "auto":
                raise ConfigError(f"crop option plane_height must be 'auto' or a number ≥ 0 (metres), got {v!r}")
            continue
        if k in _NUMBER_OPTIONS:
            low, integer = _NUMBER_OPTIONS[k]
            ok = isinstance(v, (int, np.integer)) if integer else isinstance(v, (int, float, np.integer, np.floating))
            if isinstance(v, bool) or not ok or not (math.isfinite(float(v)) and v >= low):
                raise ConfigError(f"crop option {k} must be {'an int' if integer else 'a number'} ≥ {low}, got {v!r}")
        elif k in _FLAG_OPTIONS and v is not None and not isinstance(v, (bool, np.bool_)):
            raise ConfigError(f"crop option {k} must be True, False or None, got {v!r}")
    if options.get("min_depth", 0.1) >= options.get("max_depth", 10.0):
        raise ConfigError(f"crop option min_depth ({options.get('min_depth', 0.1)}) must be below max_depth "
                          f"({options.get('max_depth', 10.0)})")
    return dict(options)


def crop_points(depth, K, *, box=None, mask=None, depth_unit="mm", image_size=None, min_depth: float = 0.1,
                max_depth: float = 10.0, max_points: int = 4096, reject_background: bool | None = None,
                outlier_k: int = 8, outlier_std: float = 2.0, min_points: int = MIN_POINTS,
                check_plausible: bool = True, remove_support_plane: bool | None = None, support_plane=None,
                plane_height: float | str = "auto", keep_base: bool = True, prevalidated: bool = False) -> CropResult:
    """Depth frame + box/mask → cleaned object points in metres.

    Convention: ``depth`` [H, W] in ``depth_unit``; ``K`` [3, 3] for ``image_size`` (W, H) or the frame itself;
    ``box`` (x, y, w, h) pixels and/or ``mask`` [H, W] bool (both → their intersection; neither → whole frame).
    Returns ``CropResult`` with points [P, 3] float32 metres in the camera frame.

    Stages: validation → region → invalid-depth removal → depth gating [``min_depth``, ``max_depth``] m → support
    plane removal (points less than ``plane_height`` m above the frame's dominant plane, or beyond it, are dropped;
    with ``keep_base`` the object's own base in that band is given back at the end, ``equipose.preprocess.base``;
    "auto": ``PLANE_NOISE_SIGMAS`` × the depth noise of the table pixels in the box, 6–12 mm, ``auto_plane_height``;
    ``support_plane`` = precomputed (normal, offset) from ``find_support_plane``; default on for a box without a
    mask, and skipped when the frame has no dominant plane or too few points would remain) → subsampling to at most
    ``max_points`` on the frame's regular pixel lattice (rows and columns that are multiples of its pitch, so a box
    moved by a pixel or the object's mask keep the same pixels of the object) → background rejection (default on for a
    box without a mask: the object the box is drawn around, ``box_object_cluster``, first among the depth clusters
    (background far behind, occluders well in front), then among the connected surfaces of that cluster on the pixel
    grid (``surface_segments``: an occluder whose depths overlap the object's), where a surface of a nearer cluster
    joins only as a part of the object grown into that cluster (a bowl's front wall before its inside); what lies in
    front of it is reported as ``diagnostics["occluded_fraction"]``) → statistical outlier removal (``outlier_std``; 0
    disables): on the pixel grid with its 8 neighbours (``organized_outlier_mask``) for the default ``outlier_k`` = 8,
    else k-d tree with k = ``outlier_k``.
    Raises ``DepthDtypeError``, ``DepthUnitError``, ``EmptyDepthError``, ``IntrinsicsError``, ``RegionError``,
    ``TooFewPointsError``. ``check_plausible=False`` skips the unit plausibility check (already-validated frames);
    ``prevalidated=True`` takes ``depth`` as the float32 metres that ``depth_to_metres`` returned for this frame and
    skips conversion and validation altogether (``PoseEstimator`` validates each frame once for all its objects).
    """
    check_crop_options({"min_depth": min_depth, "max_depth": max_depth, "max_points": max_points, "outlier_k": outlier_k,
                        "outlier_std": outlier_std, "min_points": min_points, "plane_height": plane_height})
    auto_height = isinstance(plane_height, str)                                 # "auto" (checked above)
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
    region = None
    if mask is not None:
        region = check_mask(mask, (H, W))[y0:y1, x0:x1]                         # [h, w]
        if not region.any():
            raise RegionError("the mask and the box do not overlap; pass a box that contains the mask")
    valid, counts = _window_mask(win, region, np.float32(min_depth), np.float32(max_depth))  # [h, w], [3]
    diag = {"region": int(counts[0]), "valid": int(counts[1])}
    if diag["valid"] == 0:
        raise EmptyDepthError(f"no valid depth inside the region ({diag['region']} pixels); the object may be too close, "
                              "too far, or too dark/shiny for the depth camera — check the box/mask and the depth frame")
    diag["gated"] = n_valid = int(counts[2])
    if diag["gated"] < min_points:
        raise TooFewPointsError(f"{diag['gated']} valid pixels within {min_depth}–{max_depth} m in the region (need "
                                f"≥ {min_points}); enlarge the box/mask or change min_depth/max_depth")
    if remove_support_plane is None:
        remove_support_plane = box is not None and mask is None
    band = None                                           # with keep_base: (band pixels, plane, height) removed
    if remove_support_plane:
        plane = support_plane if support_plane is not None else find_support_plane(d, Kf)
        if plane is not None:
            terms = plane_height_terms(plane, Kf, x0, y0, x1, y1)              # (ry [h], cx [w], offset)
            if auto_height:
                plane_height = auto_plane_height(_near_plane_heights(win, valid, *terms,
                                                                     np.float32(PLANE_HEIGHT_RANGE[1])))
            diag["plane_height"] = round(float(plane_height), 5)
            above, n_above, in_band = _split_at_plane(win, valid, *terms, np.float32(plane_height))  # [h, w] ×2
            if n_above >= min_points:
                if keep_base:
                    band = (in_band, plane, float(plane_height))
                valid, n_valid = above, int(n_above)
                diag["above_plane"] = n_valid
    s = 1 if n_valid <= max_points else int(math.ceil(math.sqrt(n_valid / max_points)))   # grid pitch, deterministic
    rows, cols = _lattice_pixels(valid, s, y0, x0)                              # [P], [P] frame pixels on the lattice
    if len(rows) < min_points:                                                  # pathological sparse layouts
        rows, cols = np.nonzero(valid)
        keep = np.zeros(len(rows), bool)
        keep[:: int(math.ceil(len(rows) / max_points))] = True
        rows, cols = rows[keep] + y0, cols[keep] + x0                           # frame pixels
        s = 0                                                                   # not a grid any more
    diag["subsampled"] = int(len(rows))
    pts = _backproject(d, rows, cols, Kf)                                       # [P, 3] float64 m
    z = pts[:, 2]                                                               # [P]
    if reject_background is None:
        reject_background = box is not None and mask is None
    if reject_background:
        if box is not None:                                                     # the surface the box is drawn around
            beyond = continues_beyond_box(d, z, rows, cols, (x0, y0, x1, y1), max(s, 1), float(Kf[1, 1]))  # [P]
            keep, info = box_object_cluster(z, rows, cols, (x0, y0, x1, y1), beyond=beyond, step=max(s, 1))
            if s and keep.sum() >= min_points:                                  # lattice: then among its surfaces
                nearer = z < z[keep].min()                                      # [P] the depth clusters in front
                sub = np.nonzero(keep | nearer)[0]                              # [P1] (a bowl's front wall may be one)
                labels, cut = surface_segments(z[sub], rows[sub], cols[sub], s, float(Kf[1, 1]))
                inner, info2 = box_object_cluster(z[sub], rows[sub], cols[sub], (x0, y0, x1, y1), labels=labels,
                                                  cut=cut, points=pts[sub], focal=float(Kf[1, 1]),
                                                  beyond=beyond[sub], step=s, nearer=nearer[sub])
                keep = np.zeros(len(z), bool)
                keep[sub[inner]] = True
                info = {"clusters": info["clusters"], "surfaces": info2["clusters"],
                        "front_points": info2["front_points"], "occluded_fraction": info2["occluded_fraction"]}
            diag.update(info)
        else:
            keep = nearest_depth_cluster(z)                                     # [P]
        pts, rows, cols = pts[keep], rows[keep], cols[keep]
        diag["cluster"] = int(keep.sum())
        diag["cluster_depth_m"] = float(median(pts[:, 2]))
    if outlier_std and outlier_std > 0:
        if s and outlier_k == 8:                                                # organized: the 8 grid neighbours
            keep = organized_outlier_mask(pts, rows - y0, cols - x0, step=s, std_ratio=outlier_std)  # [P]
        else:
            keep = statistical_outlier_mask(pts, k=outlier_k, std_ratio=outlier_std)  # [P]
        pts, rows, cols = pts[keep], rows[keep], cols[keep]
    if band is not None and s and len(pts):                                     # the object's own base, given back
        b_rows, b_cols = _lattice_pixels(band[0], s, y0, x0)                    # [Q], [Q] on the same lattice
        b_pts = _backproject(d, b_rows, b_cols, Kf)                             # [Q, 3] m
        spacing = median(pts[:, 2]) * s / float(Kf[1, 1])                       # m between lattice points
        facing = facing_cosines(d, b_rows, b_cols, Kf, s, np.asarray(band[1][0], np.float64))  # [Q]
        base = base_mask(pts, b_pts, band[1], band[2], spacing, facing)         # [Q]
        diag["base_points"] = int(base.sum())
        pts, rows, cols = (np.concatenate([pts, b_pts[base]]), np.concatenate([rows, b_rows[base]]),
                           np.concatenate([cols, b_cols[base]]))
    diag["inliers"] = int(len(pts))
    if len(pts) < min_points:
        raise TooFewPointsError(f"only {len(pts)} points survived the crop (need ≥ {min_points}; stages: {diag}); "
                                "enlarge the box/mask, move the camera closer, or check the depth frame")
    return CropResult(points=pts.astype(np.float32), pixels=np.stack([rows, cols], 1).astype(np.int64), K=Kf,
                      diagnostics=diag)
