"""Where the axis of a body of revolution lies, from its surface normals: every normal line of a surface of
revolution meets the axis.

A cup's, can's or bowl's side seen from one side is enough: each side point p with normal n says that the axis line
crosses the line p + s·n, i.e. u · c = u · p for u = a × n / |a × n| and any point c of the axis (direction a). The
side points' equations, solved by iteratively reweighted least squares (Cauchy weights: a mug's handle, a neighbour's
points or flying pixels at the silhouette do not meet the axis), give the axis line without the network's reading of
where the unseen back of the object is.

Convention: ``points`` [N, 3] and the axis point in one frame and unit (any); ``normals`` [N, 3] unit vectors in that
frame, sign arbitrary; ``axis`` [3] a direction (normalised here).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ["AxisLine", "axis_line", "SIDE_BAND", "MIN_SIDE_POINTS", "MIN_SPREAD"]

SIDE_BAND = 0.5             # |n · a| below this: a side normal (within 30° of perpendicular to the axis); also the
                            # cylinder stage's side normals (``equipose.runtime.cylinder.refine_side_axis``)
MIN_SIDE_POINTS = 24        # fewer side normals than this: no fit
MIN_SPREAD = 0.05           # the side normals' smaller / larger in-plane spread below this (a narrow strip of the side,
                            # whose normals barely turn): the axis' distance along the normals is not settled, no fit
SCALE_FLOOR = 0.01          # the Cauchy scale never drops below this × the points' RMS distance from ``start``


@dataclass(frozen=True)
class AxisLine:
    """The fitted axis line: ``point`` [3] (``start`` moved perpendicular to the axis), ``shift`` (its distance
    from ``start``, points' unit), ``spread`` (the side normals' smaller / larger in-plane spread), ``sides`` (side
    points used), ``residual`` (weighted RMS distance of their normal lines from the axis, points' unit)."""
    point: np.ndarray
    shift: float
    spread: float
    sides: int
    residual: float


def axis_line(points, normals, axis, start, iters: int = 6, band: float = SIDE_BAND) -> AxisLine | None:
    """The axis line of direction ``axis`` that the side normals of ``points`` meet, as the point of it nearest to
    ``start`` [3] (along the axis ``start`` is kept), or None when fewer than ``MIN_SIDE_POINTS`` side normals are
    seen or they barely turn (``MIN_SPREAD``). ``iters`` rounds of Cauchy-reweighted least squares from ``start``."""
    p = np.ascontiguousarray(points, np.float64)                                # [N, 3]
    n = np.ascontiguousarray(normals, np.float64)                               # [N, 3]
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise ValueError(f"axis_line: points and normals must both be [N, 3], got {p.shape} and {n.shape}")
    a = np.asarray(axis, np.float64).reshape(3)
    a = a / np.linalg.norm(a)
    c0 = np.asarray(start, np.float64).reshape(3)
    E = _plane_basis(a)                                                         # [3, 2] basis of the plane ⟂ a
    out = np.empty(5)                                                           # x (2), spread, sides, residual
    _fit(p, n, a, c0, E, int(iters), float(np.sqrt(1.0 - band * band)), out)
    sides, spread = int(out[3]), float(out[2])
    if sides < MIN_SIDE_POINTS or spread < MIN_SPREAD:
        return None
    x = out[:2]
    return AxisLine(point=c0 + E @ x, shift=float(np.hypot(x[0], x[1])), spread=spread, sides=sides,
                    residual=float(out[4]))


@njit(cache=True)
def _plane_basis(a):
    """[3, 2] an orthonormal basis (e1, a × e1) of the plane perpendicular to the unit ``a`` [3]."""
    h = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(a, h)
    e1 /= np.linalg.norm(e1)
    E = np.empty((3, 2))
    E[:, 0], E[:, 1] = e1, np.cross(a, e1)
    return E


@njit(cache=True, nogil=True)
def _fit(p, n, a, c0, E, iters, min_sin, out) -> None:
    """``out`` ← (x [2], spread, sides, residual) of ``axis_line``: the side points of ``p`` [N, 3] (normals ``n``
    whose sine to the unit axis ``a`` exceeds ``min_sin``) as rows U = (a × n̂)ᵀE [S, 2], b = (a × n̂)·(p − c0) [S],
    then ``iters`` rounds of Cauchy-reweighted least squares for the axis point's in-plane offset x (spread and
    residual from the last round's weights: all 1 when ``iters`` is 0). sides < ``MIN_SIDE_POINTS`` leaves the rest
    unset."""
    N = p.shape[0]
    U, b, d2 = np.empty((N, 2)), np.empty(N), 0.0
    S = 0
    for i in range(N):
        ux = a[1] * n[i, 2] - a[2] * n[i, 1]                                    # a × n
        uy = a[2] * n[i, 0] - a[0] * n[i, 2]
        uz = a[0] * n[i, 1] - a[1] * n[i, 0]
        s = np.sqrt(ux * ux + uy * uy + uz * uz)                                # sin of the normal's angle to a
        if s <= min_sin:
            continue
        ux, uy, uz = ux / s, uy / s, uz / s
        qx, qy, qz = p[i, 0] - c0[0], p[i, 1] - c0[1], p[i, 2] - c0[2]
        U[S, 0] = ux * E[0, 0] + uy * E[1, 0] + uz * E[2, 0]
        U[S, 1] = ux * E[0, 1] + uy * E[1, 1] + uz * E[2, 1]
        b[S] = ux * qx + uy * qy + uz * qz
        d2 += qx * qx + qy * qy + qz * qz
        S += 1
    out[3] = S
    if S < MIN_SIDE_POINTS:
        return
    floor = SCALE_FLOOR * np.sqrt(d2 / S)
    x0, x1 = 0.0, 0.0
    r, w = np.empty(S), np.ones(S)
    a00, a01, a11 = 0.0, 0.0, 0.0
    for i in range(S):                                                          # the unweighted normal matrix
        a00 += U[i, 0] * U[i, 0]
        a01 += U[i, 0] * U[i, 1]
        a11 += U[i, 1] * U[i, 1]
    for _ in range(iters):
        for i in range(S):
            r[i] = U[i, 0] * x0 + U[i, 1] * x1 - b[i]                           # each normal line's distance
        sigma = max(1.4826 * np.median(np.abs(r)), floor)
        a00, a01, a11, g0, g1 = 0.0, 0.0, 0.0, 0.0, 0.0
        for i in range(S):
            w[i] = 1.0 / (1.0 + (r[i] / sigma) ** 2)                            # Cauchy
            a00 += w[i] * U[i, 0] * U[i, 0]
            a01 += w[i] * U[i, 0] * U[i, 1]
            a11 += w[i] * U[i, 1] * U[i, 1]
            g0 += w[i] * U[i, 0] * b[i]
            g1 += w[i] * U[i, 1] * b[i]
        d00, d11 = a00 + 1e-12, a11 + 1e-12
        det = d00 * d11 - a01 * a01
        x0, x1 = (d11 * g0 - a01 * g1) / det, (d00 * g1 - a01 * g0) / det
    half, diff = 0.5 * (a00 + a11), np.sqrt(0.25 * (a00 - a11) ** 2 + a01 * a01)
    lo, hi = half - diff, half + diff                                           # eigenvalues of the last matrix
    out[0], out[1] = x0, x1
    out[2] = lo / hi if hi > 0.0 else 0.0
    rw, sw = 0.0, 0.0
    for i in range(S):
        ri = U[i, 0] * x0 + U[i, 1] * x1 - b[i]
        rw += w[i] * ri * ri
        sw += w[i]
    out[4] = np.sqrt(rw / sw)
