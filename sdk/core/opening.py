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
    a = np.ascontiguousarray(axis, np.float64).reshape(3)
    c = np.ascontiguousarray(centre, np.float64).reshape(3)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 10:
        raise InvalidPointsError(f"top_closure needs an [N ≥ 10, 3] cloud, got shape {p.shape}")
    norm = float(np.sqrt(a @ a))
    if not (np.isfinite(p).all() and np.isfinite(c).all() and np.isfinite(norm) and norm > 1e-12):
        raise InvalidPointsError("top_closure needs finite points, a finite centre and a non-zero axis")
    cap, bottom, taper = _top_closure(p, a / norm, c)
    return Closure(float(cap), float(bottom), float(taper))


@njit(cache=True)
def _top_closure(p, a, c):
    """``top_closure`` of the points ``p`` [N, 3] along the unit axis ``a`` [3] through ``c`` [3]."""
    n = len(p)
    # (e1, e2, a) right-handed: e1 = a × (x or y), e2 = a × e1
    ux, uy, uz = (1.0, 0.0, 0.0) if abs(a[0]) < 0.9 else (0.0, 1.0, 0.0)
    e1 = np.array([a[1] * uz - a[2] * uy, a[2] * ux - a[0] * uz, a[0] * uy - a[1] * ux])
    e1 /= np.sqrt(e1[0] ** 2 + e1[1] ** 2 + e1[2] ** 2)
    e2 = np.array([a[1] * e1[2] - a[2] * e1[1], a[2] * e1[0] - a[0] * e1[2], a[0] * e1[1] - a[1] * e1[0]])
    u, v, h = np.empty(n), np.empty(n), np.empty(n)                            # across (2) and along the axis
    for i in range(n):
        dx, dy, dz = p[i, 0] - c[0], p[i, 1] - c[1], p[i, 2] - c[2]
        u[i] = dx * e1[0] + dy * e1[1] + dz * e1[2]
        v[i] = dx * e2[0] + dy * e2[1] + dz * e2[2]
        h[i] = dx * a[0] + dy * a[1] + dz * a[2]
    hs = np.sort(h)
    lo, hi = sorted_percentile(hs, 2.0), sorted_percentile(hs, 98.0)
    q1, q2 = sorted_quantile(hs, 1.0 / 3.0), sorted_quantile(hs, 2.0 / 3.0)
    r0 = np.sqrt(u * u + v * v)                                                # [N] radii about the given centre
    suu = suv = su = svv = sv = 0.0                                            # circle fit on the middle third:
    bu = bv = b1 = 0.0                                                         # x² + y² = 2cx·x + 2cy·y + k
    m = 0
    for i in range(n):
        if q1 <= h[i] <= q2:
            x, y = 2.0 * u[i], 2.0 * v[i]
            rr = u[i] * u[i] + v[i] * v[i]
            suu += x * x
            suv += x * y
            su += x
            svv += y * y
            sv += y
            bu += x * rr
            bv += y * rr
            b1 += rr
            m += 1
    cx, cy = 0.0, 0.0
    if m >= MIN_WALL_POINTS:
        A = np.array([[suu, suv, su], [suv, svv, sv], [su, sv, float(m)]])
        if abs(np.linalg.det(A)) > 1e-300:
            sol = np.linalg.solve(A, np.array([bu, bv, b1]))
            if np.isfinite(sol[0]) and np.isfinite(sol[1]) and \
                    np.sqrt(sol[0] ** 2 + sol[1] ** 2) <= sorted_percentile(np.sort(r0), 90.0):
                cx, cy = sol[0], sol[1]
    rho = np.sqrt((u - cx) ** 2 + (v - cy) ** 2)                               # [N] distance from the axis
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
