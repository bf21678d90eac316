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
    p = np.asarray(points, np.float64)                                          # [N, 3]
    n = np.asarray(normals, np.float64)                                         # [N, 3]
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise ValueError(f"axis_line: points and normals must both be [N, 3], got {p.shape} and {n.shape}")
    a = np.asarray(axis, np.float64).reshape(3)
    a = a / np.linalg.norm(a)
    c0 = np.asarray(start, np.float64).reshape(3)
    u = np.cross(a, n)                                                          # [N, 3] ⟂ axis and normal
    s = np.linalg.norm(u, axis=1)                                               # [N] sin of the normal's angle to a
    side = s > np.sqrt(1.0 - band * band)
    if int(side.sum()) < MIN_SIDE_POINTS:
        return None
    u, p = u[side] / s[side, None], p[side]                                     # [S, 3] unit, [S, 3]
    e1 = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(a, e1)
    E = np.stack([e1, e2], 1)                                                   # [3, 2] basis of the plane ⟂ a
    U = u @ E                                                                   # [S, 2]
    b = np.einsum("ij,ij->i", u, p - c0)                                        # [S] u · (p − c0)
    floor = SCALE_FLOOR * float(np.sqrt(np.mean(np.sum((p - c0) ** 2, axis=1))))
    x = np.zeros(2)                                                             # the axis point's offset in the plane
    w = np.ones(len(b))
    A = U.T @ U                                                                 # [2, 2] the weighted normal matrix
    for _ in range(iters):
        r = U @ x - b                                                           # [S] each normal line's distance
        sigma = max(1.4826 * float(np.median(np.abs(r))), floor)
        w = 1.0 / (1.0 + (r / sigma) ** 2)                                      # [S] Cauchy
        Uw = U * w[:, None]                                                     # [S, 2]
        A = Uw.T @ U
        x = np.linalg.solve(A + 1e-12 * np.eye(2), Uw.T @ b)
    lo, hi = np.linalg.eigvalsh(A)
    spread = float(lo / hi) if hi > 0 else 0.0
    if spread < MIN_SPREAD:
        return None
    r = U @ x - b
    return AxisLine(point=c0 + E @ x, shift=float(np.linalg.norm(x)), spread=spread, sides=len(b),
                    residual=float(np.sqrt(np.sum(w * r * r) / np.sum(w))))
