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
from equipose.core.geometry import cross

__all__ = ["fit_plane_ransac", "find_support_plane"]


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
    tri = _triples(P, int(iterations), seed)                                    # [I, 3]
    a, b, c = points[tri[:, 0]], points[tri[:, 1]], points[tri[:, 2]]           # [I, 3] each
    normals = cross(b - a, c - a)                                               # [I, 3]
    norms = np.linalg.norm(normals, axis=1)                                     # [I]
    ok = norms > 1e-9
    normals, a = normals[ok] / norms[ok, None], a[ok]
    offsets = -np.einsum("ij,ij->i", normals, a)                                # [I']
    if len(normals) == 0:
        raise TooFewPointsError("plane fit failed: all sampled point triples are collinear")
    sub = np.ascontiguousarray(points[:: max(1, P // 1500)].T, np.float32)     # [3, S ≤ 3000] scoring subset
    j = _best_plane(sub, normals.astype(np.float32), offsets.astype(np.float32), np.float32(threshold),
                    float(confidence), int(chunk))
    best_n, best_d = normals[j], offsets[j]
    P64 = np.ascontiguousarray(points, np.float64)
    for _ in range(2):                                                          # least-squares refinement
        count, c0, scatter = _inlier_moments(P64, best_n, float(best_d), float(threshold))
        if count < 3:
            break
        _, vecs = np.linalg.eigh(scatter)                                       # 3×3 scatter, ascending eigenvalues
        best_n = vecs[:, 0]                                                     # least-variance direction
        best_d = -float(best_n @ c0)
    if best_d < 0:
        best_n, best_d = -best_n, -best_d
    inl = np.abs(points @ best_n + best_d) < threshold
    return best_n, float(best_d), inl


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
