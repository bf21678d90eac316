"""Is the top of a cup-like cloud open or closed, along a given axis?

A cup, mug or bowl shows its inside through its opening; upside down, it shows its closed bottom there instead. Seen
from above, the points near the axis then lie at the top of the cloud (the bottom plate), and the body narrows towards
that end (cups and bowls are wider at the opening). Both read off a single view, whatever its crop or pose:

- ``cap``: the share of the points that lie near the axis (within ``CAP_RADIUS`` × the cloud's 90th-percentile radius
  from it) *and* in the top ``CAP_HEIGHT`` of the cloud's extent along the axis. Near 0 for an open top (its inside
  lies lower), 0.1–0.3 for a closed one seen from above;
- ``bottom``: the same share at the other end (the bottom ``CAP_HEIGHT``): a cup standing on its opening and posed
  upside down shows its closed bottom there;
- ``taper``: the median radius of the top third of the points (by height) minus that of the bottom third, over the
  90th-percentile radius: positive when the body widens towards the top.

How well they tell an upside-down cup, mug or bowl from an upright one: docs/results/confidence/README.md (v0.41).

Convention: ``points`` [N, 3] and ``centre`` [3] in one unit (any), ``axis`` [3] the direction claimed to be the
opening's (normalised here); the axis passes near ``centre``. Radii are taken from a circle fitted to the side wall
(the points of the middle third by height, in the plane across the axis); where that fit fails or lands farther than
the cloud's radius from ``centre``, from ``centre`` itself.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError
from equipose.core.order_statistics import sorted_median, sorted_percentile, sorted_quantile

__all__ = ["Closure", "top_closure", "CAP_RADIUS", "CAP_HEIGHT"]

CAP_RADIUS = 0.6        # × the 90th-percentile radius: "near the axis"
CAP_HEIGHT = 0.15       # share of the height extent (2nd–98th percentile) at the top that counts as "the top"
MIN_WALL_POINTS = 20    # side-wall points needed for the circle fit


class Closure(NamedTuple):
    """``top_closure``'s reading (see the module docstring): shares of the points, and a radius ratio."""
    cap: float              # near the axis at the top
    bottom: float           # near the axis at the bottom
    taper: float            # widening towards the top


def top_closure(points, axis, centre) -> Closure:
    """``Closure`` of ``points`` along ``axis`` through ``centre`` (see the module docstring). One compiled pass.

    Raises ``InvalidPointsError`` for fewer than 10 points, a zero axis or non-finite input."""
    p = np.ascontiguousarray(points, np.float64)
    a = np.asarray(axis, np.float64).reshape(3)
    c = np.asarray(centre, np.float64).reshape(3)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 10:
        raise InvalidPointsError(f"top_closure needs an [N ≥ 10, 3] cloud, got shape {p.shape}")
    norm = float(np.linalg.norm(a))
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(c)) and np.isfinite(norm) and norm > 1e-12):
        raise InvalidPointsError("top_closure needs finite points, a finite centre and a non-zero axis")
    a = a / norm
    e1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)                                                       # (e1, e2, a) right-handed
    cap, bottom, taper = _top_closure(p - c, np.stack([e1, e2, a], axis=1))   # [N, 3] offsets, [3, 3] frame
    return Closure(float(cap), float(bottom), float(taper))


@njit(cache=True)
def _top_closure(v, frame):
    """``top_closure`` of the offsets ``v`` [N, 3] from the centre, in the columns (e1, e2, axis) of ``frame``."""
    n = len(v)
    w = v @ frame                                                              # [N, 3]: across (2), along (1)
    h = w[:, 2].copy()
    hs = np.sort(h)
    lo, hi = sorted_percentile(hs, 2.0), sorted_percentile(hs, 98.0)
    q1, q2 = sorted_quantile(hs, 1.0 / 3.0), sorted_quantile(hs, 2.0 / 3.0)
    r0 = np.sqrt(w[:, 0] ** 2 + w[:, 1] ** 2)                                  # [N] radii about the given centre
    cx, cy = 0.0, 0.0
    m = 0
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for i in range(n):                                                         # circle fit on the middle third
        if q1 <= h[i] <= q2:
            row = np.array([2.0 * w[i, 0], 2.0 * w[i, 1], 1.0])
            A += np.outer(row, row)
            b += row * (w[i, 0] ** 2 + w[i, 1] ** 2)
            m += 1
    if m >= MIN_WALL_POINTS and abs(np.linalg.det(A)) > 1e-300:
        sol = np.linalg.solve(A, b)
        if np.isfinite(sol[0]) and np.isfinite(sol[1]) and \
                np.sqrt(sol[0] ** 2 + sol[1] ** 2) <= sorted_percentile(np.sort(r0), 90.0):
            cx, cy = sol[0], sol[1]
    rho = np.sqrt((w[:, 0] - cx) ** 2 + (w[:, 1] - cy) ** 2)                   # [N] distance from the axis
    r90 = sorted_percentile(np.sort(rho), 90.0)
    if r90 <= 0.0:
        r90 = 1e-12
    top, bottom = hi - CAP_HEIGHT * (hi - lo), lo + CAP_HEIGHT * (hi - lo)
    near_top, near_bottom = 0, 0
    for i in range(n):
        if rho[i] < CAP_RADIUS * r90:
            near_top += h[i] >= top
            near_bottom += h[i] <= bottom
    taper = (sorted_median(np.sort(rho[h >= q2])) - sorted_median(np.sort(rho[h <= q1]))) / r90
    return near_top / n, near_bottom / n, taper
