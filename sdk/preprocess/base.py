"""The base of an object standing on the support plane, given back to a box crop.

A box crop drops every pixel within ``plane_height`` (6–12 mm) of the support plane, so that the table goes; the
bottom of the object standing on it goes too. A mask prompt keeps it, and the models were trained on such crops
(the renderer crops with the object's mask), so a box crop without its base places a can's centre millimetres off
the mask's (mOSD Kinect scenes: the box's centre 4.7 mm from the mask's on the median can, v0.51).

``base_mask`` takes a plane-band point as the object's when it lies under the object's own wall: its foot on the
plane (its projection along the normal) within ``reach`` of the foot of one of the object's points in its lowest
``BASE_SLICE_M``, and its surface does not face up like the table's (the depth frame's normal there, from the pixels
one lattice pitch around it, at least ``BASE_MAX_UP_DEG`` from the plane's normal). The table in front of the object
lies further out or faces up; the table behind it is hidden by the object.

Convention: metres, camera frame; ``plane`` = (unit normal [3], offset), height above it = n · p + offset (the camera
side positive).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from equipose.core.nearest import nearest_distances

__all__ = ["base_mask", "facing_cosines", "BASE_SLICE_M", "BASE_GAP_M", "BASE_REACH_SPACINGS", "BASE_MIN_REACH_M",
           "BASE_MAX_UP_DEG"]

BASE_SLICE_M = 0.01          # the object's lowest visible 1 cm: the wall whose foot the band continues
BASE_GAP_M = 0.01            # its lowest point at most this above the band: else it does not stand on the plane here
BASE_REACH_SPACINGS = 1.0    # reach = this × the crop's point spacing on the object ...
BASE_MIN_REACH_M = 0.003     # ... and at least this
BASE_MAX_UP_DEG = 45.0       # a surface whose normal lies within this of the plane's faces up: the table


@njit(cache=True)
def facing_cosines(d, rows, cols, K, step, normal) -> np.ndarray:
    """[Q] |cos| of the angle between ``normal`` [3] and the depth surface at the pixels (``rows``, ``cols``) [Q] of
    ``d`` [H, W] metres (0 = invalid), from central differences ``step`` pixels wide; 1 (facing up, not the object's)
    where a neighbour is missing or the surface is degenerate (the pinhole's skew left out: a direction only)."""
    H, W = d.shape
    out = np.ones(len(rows))
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    for q in range(len(rows)):
        r, c = rows[q], cols[q]
        if r - step < 0 or r + step >= H or c - step < 0 or c + step >= W:
            continue
        zl, zr, zu, zd = d[r, c - step], d[r, c + step], d[r - step, c], d[r + step, c]
        if not (zl > 0 and zr > 0 and zu > 0 and zd > 0):
            continue
        ax = ((c + step - cx) * zr - (c - step - cx) * zl) / fx                 # horizontal difference [3]
        ay = (r - cy) * (zr - zl) / fy
        az = zr - zl
        bx = (c - cx) * (zd - zu) / fx                                          # vertical difference [3]
        by = ((r + step - cy) * zd - (r - step - cy) * zu) / fy
        bz = zd - zu
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        if norm > 0:
            out[q] = abs(nx * normal[0] + ny * normal[1] + nz * normal[2]) / norm
    return out


def base_mask(object_points: np.ndarray, band_points: np.ndarray, plane, plane_height: float,
              spacing: float, facing=None) -> np.ndarray:
    """[Q] bool: which ``band_points`` [Q, 3] (the box's pixels within ``plane_height`` m of ``plane``) continue the
    wall of ``object_points`` [P, 3] down to the plane. ``spacing``: the crop's point spacing on the object (m: depth
    × lattice pitch / focal length); ``facing`` [Q]: ``facing_cosines`` of the band points (None: not tested). None of
    them when the object's lowest point is more than ``BASE_GAP_M`` above the band (it stands on something else, or
    its base is hidden)."""
    if len(band_points) == 0 or len(object_points) == 0:
        return np.zeros(len(band_points), bool)
    n = np.asarray(plane[0], np.float64)                                       # [3] unit normal
    off = float(plane[1])
    h = object_points @ n + off                                                 # [P] m above the plane
    low = float(h.min())
    if low > plane_height + BASE_GAP_M:
        return np.zeros(len(band_points), bool)
    b = np.asarray(band_points, np.float64)                                    # [Q, 3]
    wall = object_points[h <= low + BASE_SLICE_M]                               # [W, 3] the lowest slice
    feet_wall = wall - np.outer(wall @ n, n)                                    # [W, 3] along the normal onto n·p = 0
    feet_band = b - np.outer(b @ n, n)                                          # [Q, 3]
    reach = max(BASE_MIN_REACH_M, BASE_REACH_SPACINGS * float(spacing))
    keep = nearest_distances(feet_wall, feet_band) <= reach                     # [Q]
    if facing is not None:
        keep &= np.asarray(facing) < np.cos(np.radians(BASE_MAX_UP_DEG))
    return keep
