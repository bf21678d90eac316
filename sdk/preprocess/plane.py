"""Dominant-plane fitting (table, floor): adaptive RANSAC with a least-squares refit.

Convention: points ``[P, 3]`` metres in the camera frame; a plane is (normal [3] unit, offset d) with ``n · x + d = 0``,
oriented so the camera origin has positive signed distance.
"""
from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from equipose.core.errors import TooFewPointsError
from equipose.core.eigen import top_eigenvector
from equipose.core.order_statistics import median

__all__ = ["fit_plane_ransac", "find_support_plane", "plane_height_terms", "densest_level", "local_support_plane",
           "LOCAL_LIFT_M", "LOCAL_BAND_M"]

LOCAL_LIFT_M = 0.03     # a region whose surrounding surface lies this far above the frame's plane stands on it
LOCAL_BAND_M = 0.01     # ... found as the most populated slice this high of the region's lower half


@njit(cache=True)
def _best_plane(sub, normals, offsets, threshold, confidence, chunk) -> int:
    """Index of the hypothesis (``normals`` [I, 3], ``offsets`` [I] float32) with the most points of ``sub``
    [3, S] float32 within ``threshold``, scored ``chunk`` at a time until a better, missed plane is unlikely."""
    S = sub.shape[1]
    best_count, j = -1, 0
    for lo in range(0, len(normals), chunk):
        hi = min(lo + chunk, len(normals))
        for h in range(lo, hi):
            n0, n1, n2, o = normals[h, 0], normals[h, 1], normals[h, 2], offsets[h]
            count = 0
            for i in range(S):
                dist = o + sub[0, i] * n0 + sub[1, i] * n1 + sub[2, i] * n2             # float32, signed
                count += abs(dist) < threshold
            if count > best_count:
                best_count, j = count, h
        w = best_count / S                                                      # inlier fraction of the best so far
        if w >= 1 or hi >= math.log(1 - confidence) / math.log(max(1e-12, 1 - w ** 3)):
            break                                                               # P(missed better plane) < 1 − conf.
    return j


@njit(cache=True)
def _inlier_moments(points, n, d, threshold) -> tuple:
    """(count, centroid [3], scatter Σ (q − c)(q − c)ᵀ [3, 3]) of the points [P, 3] within ``threshold`` of the
    plane n · x + d = 0 (two passes: centroid, then scatter)."""
    c = np.zeros(3)
    count = 0
    for i in range(len(points)):
        if abs(points[i, 0] * n[0] + points[i, 1] * n[1] + points[i, 2] * n[2] + d) < threshold:
            count += 1
            for a in range(3):
                c[a] += points[i, a]
    S = np.zeros((3, 3))
    if count == 0:
        return count, c, S
    c /= count
    for i in range(len(points)):
        if abs(points[i, 0] * n[0] + points[i, 1] * n[1] + points[i, 2] * n[2] + d) < threshold:
            for a in range(3):
                for b in range(3):
                    S[a, b] += (points[i, a] - c[a]) * (points[i, b] - c[b])
    return count, c, S


def _triples(P: int, iterations: int, seed) -> np.ndarray:
    """[iterations, 3] random point indices below ``P`` from ``seed``. An int seed's triples are drawn once and kept
    (read-only: a camera's frames keep nearly the same number of valid lattice points); any other seed (None, a
    ``Generator``) draws afresh, as ``np.random.default_rng`` does."""
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        return _seeded_triples(P, iterations, int(seed))
    return np.random.default_rng(seed).integers(0, P, size=(iterations, 3))


@functools.lru_cache(maxsize=32)
def _seeded_triples(P: int, iterations: int, seed: int) -> np.ndarray:
    tri = np.random.default_rng(seed).integers(0, P, size=(iterations, 3))
    tri.flags.writeable = False
    return tri


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
    P64 = np.ascontiguousarray(points, np.float64)                             # [P, 3]
    tri = _triples(P, int(iterations), seed)                                    # [I, 3]
    normals, offsets = _plane_hypotheses(P64, tri)                              # [I', 3], [I']
    if len(normals) == 0:
        raise TooFewPointsError("plane fit failed: all sampled point triples are collinear")
    sub = np.ascontiguousarray(P64[:: max(1, P // 1500)].T, np.float32)        # [3, S ≤ 3000] scoring subset
    j = _best_plane(sub, normals.astype(np.float32), offsets.astype(np.float32), np.float32(threshold),
                    float(confidence), int(chunk))
    best_n, best_d = _refit(P64, normals[j], float(offsets[j]), float(threshold))
    inl = np.abs(P64 @ best_n + best_d) < threshold                             # [P]
    return best_n, best_d, inl


@njit(cache=True)
def _plane_hypotheses(points, tri) -> tuple:
    """(unit normals [I', 3], offsets [I']) float64 of the planes through the point triples ``tri`` [I, 3] of
    ``points`` [P, 3] float64, in the order of ``tri``, collinear triples dropped."""
    normals, offsets = np.empty((len(tri), 3)), np.empty(len(tri))
    m = 0
    for t in range(len(tri)):
        a, b, c = points[tri[t, 0]], points[tri[t, 1]], points[tri[t, 2]]
        u0, u1, u2 = b[0] - a[0], b[1] - a[1], b[2] - a[2]
        v0, v1, v2 = c[0] - a[0], c[1] - a[1], c[2] - a[2]
        n0, n1, n2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0    # (b − a) × (c − a)
        norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        if norm <= 1e-9:                                                        # collinear
            continue
        n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
        normals[m, 0], normals[m, 1], normals[m, 2] = n0, n1, n2
        offsets[m] = -(n0 * a[0] + n1 * a[1] + n2 * a[2])
        m += 1
    return normals[:m], offsets[:m]


@njit(cache=True)
def _refit(points, n, d, threshold) -> tuple:
    """(normal [3], offset) of plane (``n`` [3], ``d``) refit twice by least squares on its inliers within
    ``threshold`` in ``points`` [P, 3] float64 (the scatter's least-variance direction), oriented so that d ≥ 0."""
    n = n.copy()
    for _ in range(2):
        count, c0, scatter = _inlier_moments(points, n, d, threshold)
        if count < 3:
            break
        # least-variance direction of the scatter = the top eigenvector of trace · I − scatter
        n = top_eigenvector(np.trace(scatter) * np.eye(3) - scatter)
        d = -(n[0] * c0[0] + n[1] * c0[1] + n[2] * c0[2])
    if d < 0:
        n, d = -n, -d
    return n, d


def find_support_plane(depth_m: np.ndarray, K: np.ndarray, *, threshold: float = 0.012, min_fraction: float = 0.2,
                       grid: int = 8, seed: int = 0):
    """The frame's dominant plane (table, floor) if it is dominant enough, else None.

    Convention: ``depth_m`` [H, W] float metres (0 = invalid), ``K`` [3, 3] for this frame. RANSAC on a ``grid``-pixel
    lattice; the plane counts when at least ``min_fraction`` of the lattice's valid points are within ``threshold``.
    Returns (normal [3], offset) oriented so the camera side is positive (see ``fit_plane_ransac``), or None.
    """
    K = np.asarray(K, np.float64)
    pts = _lattice_points(np.asarray(depth_m), int(grid), K[0, 0], K[1, 1], K[0, 2], K[1, 2])  # [S, 3] m
    if len(pts) < 100:
        return None
    n, off, inl = fit_plane_ransac(pts, threshold=threshold, seed=seed)
    return (n, off) if inl.mean() >= min_fraction else None


def plane_height_terms(plane, K, x0, y0, x1, y1) -> tuple:
    """The separable terms of the height above ``plane`` (normal [3], offset) of a frame pixel (row, col) at depth z
    in the window x0 ≤ col < x1, y0 ≤ row < y1: z · (ry[row − y0] + cx[col − x0]) + offset.
    Returns (ry [h] float64, cx [w] float64, offset float32)."""
    n, off = plane
    cx = (np.arange(x0, x1, dtype=np.float32) - K[0, 2]) / K[0, 0] * n[0]                 # [w]
    ry = (np.arange(y0, y1, dtype=np.float32) - K[1, 2]) / K[1, 1] * n[1] + n[2]          # [h]
    return ry, cx, np.float32(off)


def densest_level(heights: np.ndarray, start: float, stop: float, width: float) -> tuple:
    """The most populated slice ``width`` high of ``heights`` [P] m, slices from ``start`` up to and past ``stop``:
    (median height of its points, their count), or (None, 0) when there is less than one slice."""
    edges = np.arange(start, stop + width, width)
    if len(edges) < 2:
        return None, 0
    counts = np.histogram(heights, edges)[0]
    k = int(np.argmax(counts))
    return median(heights[(heights >= edges[k]) & (heights <= edges[k + 1])]), int(counts[k])


def local_support_plane(depth_m: np.ndarray, K: np.ndarray, plane, bounds, *, margin: float = 0.25,
                        max_pixels: int = 1024, lift: float = LOCAL_LIFT_M, band: float = LOCAL_BAND_M):
    """The level an object in ``bounds`` stands on: the frame's plane, or a parallel one under the object.

    Convention: ``depth_m`` [H, W] metres (0 = invalid), ``K`` [3, 3]; ``plane`` (unit normal [3], offset) as
    ``find_support_plane`` returns it (a camera-frame point x lies ``n · x + offset`` m above it); ``bounds`` (x0, y0,
    x1, y1) pixels, x1 and y1 exclusive, grown by ``margin`` of its size on each side (what surrounds the object).
    The frame's dominant plane is the floor when the floor fills more of the view than the table: the table's
    objects then stand half a metre above it. The level is the most populated ``band``-high slice of the lower half
    of the region's pixel heights (a flat top around the object fills one slice; the object's sides spread over
    many). Where it lies more than ``lift`` above the plane, the plane moves up to it, parallel. Returns (normal,
    offset); the plane as given where its level is already under the region.
    """
    if plane is None:
        return None
    H, W = depth_m.shape
    x0, y0, x1, y1 = (int(b) for b in bounds)
    gx, gy = int(round(margin * (x1 - x0))), int(round(margin * (y1 - y0)))
    x0, y0, x1, y1 = max(x0 - gx, 0), max(y0 - gy, 0), min(x1 + gx, W), min(y1 + gy, H)
    if x1 <= x0 or y1 <= y0:
        return plane
    step = max(1, int(math.ceil(math.sqrt((x1 - x0) * (y1 - y0) / max_pixels))))
    win = np.asarray(depth_m[y0:y1:step, x0:x1:step], np.float64)               # [h, w] m
    rows, cols = np.nonzero(win > 0)
    if len(rows) < 20:
        return plane
    n, off = np.asarray(plane[0], np.float64), float(plane[1])
    ry, cx, _ = plane_height_terms((n, off), np.asarray(K, np.float64), x0, y0, x1, y1)  # [h], [w] full window
    h = win[rows, cols] * (ry[::step][rows] + cx[::step][cols]) + off           # [P] m above the plane
    low = h[h <= median(h)]                                                     # [P'] the lower half
    level, _ = densest_level(low, low.min(), low.max(), band)                   # the most populated level
    return plane if level is None or level <= lift else (n, off - level)


@njit(cache=True)
def _lattice_points(depth, grid, fx, fy, cx, cy):
    """[S, 3] float64 metres: the valid pixels (depth > 0) of every ``grid``-th row and column of ``depth`` [H, W]
    metres, back-projected (pinhole, no skew), in row-major order."""
    H, W = depth.shape
    out = np.empty(((H + grid - 1) // grid * ((W + grid - 1) // grid), 3))
    m = 0
    for r in range(0, H, grid):
        for c in range(0, W, grid):
            z = np.float64(depth[r, c])
            if z > 0:
                out[m, 0], out[m, 1], out[m, 2] = (c - cx) * z / fx, (r - cy) * z / fy, z
                m += 1
    return out[:m]
