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
from equipose.preprocess.plane import find_support_plane
from equipose.preprocess.sampling import MIN_POINTS
from equipose.preprocess.validate import check_box, check_intrinsics, check_mask, depth_to_metres

__all__ = ["CropResult", "check_crop_options", "crop_points", "statistical_outlier_mask", "organized_outlier_mask",
           "nearest_depth_cluster", "depth_clusters", "surface_segments", "box_object_cluster", "occluded_fraction"]


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
            clusters, dropped).
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
    r = (rows - rows.min()) // step                                             # [P] grid coordinates
    c = (cols - cols.min()) // step
    total, count = _grid_neighbour_distances(np.ascontiguousarray(points, np.float32), r, c)   # [P], [P]
    has = count > 0
    if has.sum() < 10:
        return has
    mean_d = (total[has] / count[has]).astype(np.float64)                       # [P']
    thr = mean_d.mean() + std_ratio * mean_d.std()
    keep = np.zeros(P, dtype=bool)
    keep[has] = mean_d <= thr
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
    labels = depth_clusters(z, gap_m, rel_gap)                                  # [P], nearest = 0
    counts = np.bincount(labels)                                                # [C]
    big = np.nonzero(counts >= max(1, min_fraction * P))[0]
    chosen = int(big[0]) if len(big) else int(np.argmax(counts))
    return labels == chosen


def depth_clusters(z: np.ndarray, gap_m: float = 0.03, rel_gap: float = 0.03) -> np.ndarray:
    """[P] cluster label of each depth in ``z`` [P] metres, 0 = nearest: sorted depths split wherever consecutive
    values differ by more than max(``gap_m``, ``rel_gap`` · z)."""
    order = np.argsort(z, kind="stable")                                        # [P]
    zs = z[order]
    gaps = np.diff(zs) > np.maximum(gap_m, rel_gap * zs[:-1])                   # [P-1]
    labels = np.empty(len(z), np.int64)
    labels[order] = np.concatenate([[0], np.cumsum(gaps)]) if len(z) else []
    return labels


def surface_segments(z: np.ndarray, rows: np.ndarray, cols: np.ndarray, step: int, focal: float,
                     min_jump: float = 0.012, slant: float = 4.0) -> tuple:
    """Connected surfaces of an organized crop.

    Convention: ``z`` [P] metres of points on a regular pixel lattice of pitch ``step`` (``rows``, ``cols`` [P] frame
    pixels); ``focal`` pixels. Lattice neighbours (4-connected) belong to one surface when their depths differ by less
    than max(``min_jump`` · max(1, z²), ``slant`` · step · z / focal): the sensor's noise grows with z², and a surface
    slanted away from the camera steps by up to ``slant`` lattice spacings per pixel. An occluder standing in front
    of the object is its own surface even where its depths overlap the object's, which a split of the depth values
    alone cannot tell apart.
    Returns (labels [P] int, 0 = the nearest surface by mean depth; cut (i [L], j [L]): the neighbour pairs split
    by a depth jump, ``z[j] − z[i]`` the jump).
    """
    import cv2
    P = len(z)
    gi, gj = (rows - rows.min()) // step, (cols - cols.min()) // step          # [P] lattice indices
    gh, gw = int(gi.max()) + 1, int(gj.max()) + 1
    grid = np.full((gh + 1, gw + 1), -1, np.int64)                              # padded: shifts never wrap
    grid[gi, gj] = np.arange(P)
    a = np.concatenate([grid[:-1, :].ravel(), grid[:, :-1].ravel()])           # each point and its lower / right
    b = np.concatenate([grid[1:, :].ravel(), grid[:, 1:].ravel()])             # neighbour
    ok = (a >= 0) & (b >= 0)
    a, b = a[ok], b[ok]
    zm = 0.5 * (z[a] + z[b])
    tol = np.maximum(min_jump * np.maximum(1.0, zm * zm), slant * step * zm / focal)
    link = np.abs(z[a] - z[b]) < tol
    # components on a doubled image: points at even cells, a kept link lights the cell between its two points
    img = np.zeros((2 * gh - 1, 2 * gw - 1), np.uint8)
    img[2 * gi, 2 * gj] = 1
    la, lb = a[link], b[link]
    img[gi[la] + gi[lb], gj[la] + gj[lb]] = 1
    _, lab = cv2.connectedComponents(img, connectivity=4)
    comp = lab[2 * gi, 2 * gj] - 1                                              # [P], 0-based
    n = int(comp.max()) + 1
    mean = np.bincount(comp, weights=z, minlength=n) / np.bincount(comp, minlength=n)     # [n] mean depth
    rank = np.empty(n, np.int64)
    rank[np.argsort(mean, kind="stable")] = np.arange(n)
    return rank[comp], (a[~link], b[~link])


def _boundary_jumps(labels: np.ndarray, z: np.ndarray, cut: tuple, inside: np.ndarray) -> dict:
    """{segment: median depth jump (m) from the ``inside`` points [P] bool to it, over their cut neighbour pairs}
    for every segment outside that borders the inside; > 0: it lies behind, < 0: in front."""
    i, j = cut
    cross = inside[i] != inside[j]
    i, j = i[cross], j[cross]
    swap = ~inside[i]                                                            # orient pairs inside → outside
    i, j = np.where(swap, j, i), np.where(swap, i, j)
    out = {}
    for seg in np.unique(labels[j]):
        sel = labels[j] == seg
        out[int(seg)] = float(np.median(z[j[sel]] - z[i[sel]]))
    return out


def _radius(points: np.ndarray) -> float:
    """Robust radius (m) of a point set [P, 3]: the 95th percentile distance from the centre of its 2–98 % box (a
    partial view's median lies off the object's centre, towards the camera)."""
    lo, hi = np.percentile(points, [2.0, 98.0], axis=0)                          # [3], [3]
    return float(np.percentile(np.linalg.norm(points - 0.5 * (lo + hi), axis=1), 95))


def _grow(seed: int, labels: np.ndarray, z: np.ndarray, cut: tuple, points: np.ndarray, max_radius: float) -> tuple:
    """The object grown from surface ``seed``: the surfaces bordering it from behind join (smallest depth jump first)
    while the union's radius stays within ``max_radius`` — a cup's front wall and its inside beyond the rim are two
    surfaces of one object, while what stands in front of an object never joins it, and the wall behind makes the
    union too large. Returns (members [P] bool, {bordering surface left out: its median jump, < 0 = in front})."""
    keep = labels == seed
    for _ in range(32):                                                         # rounds of growth
        jumps = _boundary_jumps(labels, z, cut, keep)
        grown = False
        for seg, jump in sorted(jumps.items(), key=lambda kv: kv[1]):           # nearest in depth first
            if not 0.0 < jump <= 2.0 * max_radius:                              # only what it hides in part
                continue
            union = keep | (labels == seg)
            if _radius(points[union]) <= max_radius:
                keep, grown = union, True
        if not grown:
            return keep, jumps
    return keep, _boundary_jumps(labels, z, cut, keep)


def box_object_cluster(z: np.ndarray, rows: np.ndarray, cols: np.ndarray, box, min_fraction: float = 0.1,
                       border: float = 0.08, labels: np.ndarray | None = None, cut: tuple | None = None,
                       points: np.ndarray | None = None, focal: float | None = None) -> tuple:
    """The object a box prompt is drawn around, chosen by evidence instead of nearness.

    Convention: ``z`` [P] metres, ``rows``, ``cols`` [P] frame pixels of the box's points; ``box`` (x0, y0, x1, y1)
    pixel bounds. Candidates: with ``labels`` [P] (0 = nearest), ``cut`` (``surface_segments``), ``points`` [P, 3]
    metres and ``focal`` pixels, each surface holding at least ``min_fraction`` of the points, grown by the surfaces it
    hides in part while the union fits in a sphere of half the box's diagonal at its depth (``_grow``: the box bounds
    the object's size); otherwise the split of the depth values (``depth_clusters``).

    Each candidate scores share × fit × exp(−2 d²), d the offset of its pixel centroid from the box centre in half-box
    units (a detector's box is centred on its object). Depth clusters: fit = 1 − the candidate's share of the box's
    border band (the outer ``border`` of each side), as background surrounds the object along the border. Surfaces:
    fit = the share of the box's width × height its pixels span (the box spans its object, not what stands in front
    of it), × 0.3 when it still borders from in front a large surface that does not reach all four sides of the box
    (it hides another object: an occluder; background reaches every side).
    Returns ([P] bool, info {"clusters", "front_points", "occluded_fraction": front points / (those + the object's)}):
    in front = the depth clusters nearer than the chosen one, or the surfaces bordering the grown object from in front.
    """
    P = len(z)
    if P == 0:
        return np.zeros(0, bool), {"clusters": 0, "front_points": 0, "occluded_fraction": 0.0}
    grow = labels is not None and cut is not None and points is not None and focal
    labels = depth_clusters(z) if labels is None else np.asarray(labels)
    counts = np.bincount(labels)                                                # [C], label 0 nearest
    big = np.nonzero(counts >= max(1, min_fraction * P))[0]
    if not len(big):
        big = np.array([int(np.argmax(counts))])
    x0, y0, x1, y1 = box
    if grow:
        cands = []
        for seg in big:                                                         # the box bounds the object's size too
            zs = float(np.median(z[labels == seg]))
            half_diag = 0.5 * math.hypot(x1 - x0, y1 - y0) * zs / focal
            cands.append(_grow(int(seg), labels, z, cut, points, half_diag))
    else:
        cands = [(labels == seg, None) for seg in big]
    cx, cy, hw, hh = (x0 + x1) / 2.0, (y0 + y1) / 2.0, max((x1 - x0) / 2.0, 1.0), max((y1 - y0) / 2.0, 1.0)
    sides = np.stack([cols - x0 < 2 * border * hw, x1 - 1 - cols < 2 * border * hw,
                      rows - y0 < 2 * border * hh, y1 - 1 - rows < 2 * border * hh])   # [4, P] near each side
    if grow:                                # surfaces reaching every side of the box: background all round
        enclosing = np.all([np.bincount(labels, weights=side, minlength=len(counts)) > 0 for side in sides], 0)
    else:
        band = sides.any(0)                                                     # [P] in the border band
    scores = []
    for members, jumps in cands:
        n = int(members.sum())
        offset2 = ((cols[members].mean() - cx) / hw) ** 2 + ((rows[members].mean() - cy) / hh) ** 2
        if jumps is None:                                   # depth clusters: background surrounds the object
            fit = 1.0 - band[members].sum() / max(band.sum(), 1)
        else:                                               # surfaces: the box spans its object, which hides nothing
            span = (np.ptp(cols[members]) + 1) / (2 * hw) * (np.ptp(rows[members]) + 1) / (2 * hh)
            hides = any(jump > 0 and counts[seg] >= min_fraction * P and not enclosing[seg]
                        for seg, jump in jumps.items())     # a large surface behind it, not background all round
            fit = min(span, 1.0) * (0.3 if hides else 1.0)
        scores.append(n / P * fit * np.exp(-2.0 * offset2))
    best = int(np.argmax(scores))
    keep, jumps = cands[best]
    if jumps is None:                                                           # depth clusters: nearer = in front
        front = int(counts[: int(big[best])].sum())
    else:
        front = int(sum(counts[seg] for seg, jump in jumps.items() if jump < 0.0))
    return keep, {"clusters": int(len(big)), "front_points": front, "occluded_fraction": occluded_fraction(front, keep)}


def occluded_fraction(front: int, kept: np.ndarray) -> float:
    """Share of an object's view taken by ``front`` points in front of it: front / (front + its ``kept`` [P] bool)."""
    return round(front / max(front + int(np.count_nonzero(kept)), 1), 4)


# ----------------------------------------------------------------------------------------------------------------------
# Crop

_NUMBER_OPTIONS = {  # option: (lowest allowed, integer?)
    "min_depth": (0.0, False), "max_depth": (0.0, False), "max_points": (MIN_POINTS, True), "outlier_k": (1, True),
    "outlier_std": (0.0, False), "min_points": (1, True), "plane_height": (0.0, False)}
_FLAG_OPTIONS = ("reject_background", "check_plausible", "remove_support_plane", "prevalidated")


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
                plane_height: float = 0.012, prevalidated: bool = False) -> CropResult:
    """Depth frame + box/mask → cleaned object points in metres.

    Convention: ``depth`` [H, W] in ``depth_unit``; ``K`` [3, 3] for ``image_size`` (W, H) or the frame itself;
    ``box`` (x, y, w, h) pixels and/or ``mask`` [H, W] bool (both → their intersection; neither → whole frame).
    Returns ``CropResult`` with points [P, 3] float32 metres in the camera frame.

    Stages: validation → region → invalid-depth removal → depth gating [``min_depth``, ``max_depth``] m → support
    plane removal (points less than ``plane_height`` above the frame's dominant plane, or beyond it, are dropped;
    ``support_plane`` = precomputed (normal, offset) from ``find_support_plane``; default on for a box without a
    mask, and skipped when the frame has no dominant plane or too few points would remain) → regular pixel-grid
    subsampling to at most ``max_points`` → background rejection (default on for a box without a mask: the object
    the box is drawn around, ``box_object_cluster``, first among the depth clusters (background far behind, occluders
    well in front), then among the connected surfaces of that cluster on the pixel grid (``surface_segments``: an
    occluder whose depths overlap the object's); what lies in front of it is reported as
    ``diagnostics["occluded_fraction"]``) → statistical outlier removal (``outlier_std``; 0 disables): on the pixel grid with its 8
    neighbours (``organized_outlier_mask``) for the default ``outlier_k`` = 8, else k-d tree with k = ``outlier_k``.
    Raises ``DepthDtypeError``, ``DepthUnitError``, ``EmptyDepthError``, ``IntrinsicsError``, ``RegionError``,
    ``TooFewPointsError``. ``check_plausible=False`` skips the unit plausibility check (already-validated frames);
    ``prevalidated=True`` takes ``depth`` as the float32 metres that ``depth_to_metres`` returned for this frame and
    skips conversion and validation altogether (``PoseEstimator`` validates each frame once for all its objects).
    """
    check_crop_options({"min_depth": min_depth, "max_depth": max_depth, "max_points": max_points, "outlier_k": outlier_k,
                        "outlier_std": outlier_std, "min_points": min_points, "plane_height": plane_height})
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
            keep = np.zeros(len(rows), bool)
            keep[:: int(math.ceil(len(rows) / max_points))] = True
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
        if box is not None:                                                     # the surface the box is drawn around
            keep, info = box_object_cluster(z, rows, cols, (x0, y0, x1, y1))  # [P] among the depth clusters
            if s and keep.sum() >= min_points:                                  # lattice: then among its surfaces
                sub = np.nonzero(keep)[0]                                       # [P1]
                labels, cut = surface_segments(z[sub], rows[sub], cols[sub], s, float(Kf[1, 1]))
                inner, info2 = box_object_cluster(z[sub], rows[sub], cols[sub], (x0, y0, x1, y1), labels=labels,
                                                  cut=cut, points=pts[sub], focal=float(Kf[1, 1]))
                keep = np.zeros(len(z), bool)
                keep[sub[inner]] = True
                front = info["front_points"] + info2["front_points"]
                info = {"clusters": info["clusters"], "surfaces": info2["clusters"], "front_points": front,
                        "occluded_fraction": occluded_fraction(front, keep)}
            diag.update(info)
        else:
            keep = nearest_depth_cluster(z)                                     # [P]
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
