"""Which points are vertices of their 3-D convex hull: a compiled quickhull for the small sets of the SDK's hot path.

The view stage runs hidden point removal (``equipose.runtime.visibility``) on a posed template of a few hundred
points for every hypothesis it ranks and needs only the hull's vertex set, which this loop finds about three times
faster than ``scipy.spatial.ConvexHull`` (qhull) builds the whole hull (docs/benchmarks.md, v0.38).

Convention: ``points`` [N, 3] float64, any unit. A point closer than ``HULL_EPS`` × the set's extent to the hull of
the others is not a vertex (qhull calls such points coplanar and leaves them out of ``vertices`` too). Where points
lie exactly on a face (integer grids) the two may pick different ones of them; otherwise the vertex sets agree
(tests/sdk/test_sdk_hull.py). Quickhull:
start from a tetrahedron of extreme points, then repeatedly add the farthest point outside a facet, replace the
facets it sees by a fan from it to their horizon, and hand the seen facets' outside points to the new ones. Facets
are triangles wound counter-clockwise seen from outside; ``nb[f, k]`` is the facet across edge k (from vertex k to
vertex k + 1).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError

__all__ = ["hull_vertex_mask", "HULL_EPS"]

HULL_EPS = 1e-11            # the "outside a facet" margin, relative to the point set's extent
_OK, _FLAT, _FAILED, _FULL = 0, 1, 2, 3
ROOM = 6                    # facets allotted per point (a retry gets 4× as many when a hull needs more)


def hull_vertex_mask(points: np.ndarray, check: bool = True) -> tuple:
    """(mask [N] bool: the points that are vertices of the convex hull, status): status "ok"; "flat" when the
    points span no volume (all of them within the margin of one plane: no mask, every entry False); "failed" when
    the margin could not keep the hull consistent (nearly degenerate input: use qhull instead). ``check=False``
    skips the finite-value check (for callers whose points are finite by construction)."""
    P = np.ascontiguousarray(points, np.float64)
    if P.ndim != 2 or P.shape[1] != 3:
        raise InvalidPointsError(f"hull_vertex_mask needs points [N, 3], got {P.shape}")
    mask = np.zeros(len(P), np.bool_)
    if len(P) < 4:
        return mask, "flat"
    if check and not np.all(np.isfinite(P)):
        raise InvalidPointsError("hull_vertex_mask: points contain NaN/Inf")
    status = _quickhull(P, HULL_EPS, mask, ROOM * len(P) + 64)
    if status == _FULL:
        mask[:] = False
        status = _quickhull(P, HULL_EPS, mask, 4 * ROOM * len(P) + 64)
    return mask, ("ok", "flat", "failed", "failed")[status]


@njit(cache=True, nogil=True)
def _plane(P, a, b, c, normals, offsets, f) -> bool:
    """Facet f's unit normal and offset from its corners (a, b, c), counter-clockwise; False if it has no area."""
    ux, uy, uz = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
    vx, vy, vz = P[c, 0] - P[a, 0], P[c, 1] - P[a, 1], P[c, 2] - P[a, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    if norm == 0.0:
        return False
    normals[f, 0], normals[f, 1], normals[f, 2] = nx / norm, ny / norm, nz / norm
    offsets[f] = normals[f, 0] * P[a, 0] + normals[f, 1] * P[a, 1] + normals[f, 2] * P[a, 2]
    return True


@njit(cache=True, inline="always")
def _height(P, i, normals, offsets, f) -> float:
    return normals[f, 0] * P[i, 0] + normals[f, 1] * P[i, 1] + normals[f, 2] * P[i, 2] - offsets[f]


@njit(cache=True)
def _farthest_from_line(P, a, b) -> tuple:
    ux, uy, uz = P[b, 0] - P[a, 0], P[b, 1] - P[a, 1], P[b, 2] - P[a, 2]
    best, arg = -1.0, -1
    for i in range(len(P)):
        wx, wy, wz = P[i, 0] - P[a, 0], P[i, 1] - P[a, 1], P[i, 2] - P[a, 2]
        cx, cy, cz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
        d = cx * cx + cy * cy + cz * cz
        if d > best:
            best, arg = d, i
    return arg, np.sqrt(best / (ux * ux + uy * uy + uz * uz))


@njit(cache=True, nogil=True)
def _quickhull(P, eps_rel, mask, cap) -> int:
    N = len(P)
    lo, hi = P[0].copy(), P[0].copy()
    for i in range(N):
        for k in range(3):
            lo[k] = min(lo[k], P[i, k])
            hi[k] = max(hi[k], P[i, k])
    extent = max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2])
    if extent == 0.0:
        return _FLAT
    eps = eps_rel * extent

    # the starting tetrahedron: the farthest pair of axis extremes, the point farthest from their line, the point
    # farthest from their plane
    ext = np.empty(6, np.int64)
    for k in range(3):
        ext[2 * k], ext[2 * k + 1] = np.argmin(P[:, k]), np.argmax(P[:, k])
    a, b, best = ext[0], ext[1], -1.0
    for i in range(6):
        for j in range(i + 1, 6):
            d = ((P[ext[i]] - P[ext[j]]) ** 2).sum()
            if d > best:
                best, a, b = d, ext[i], ext[j]
    c, dist_c = _farthest_from_line(P, a, b)
    if dist_c <= eps:
        return _FLAT
    fv = np.empty((cap, 3), np.int64)
    nb = np.empty((cap, 3), np.int64)
    normals = np.empty((cap, 3))
    offsets = np.empty(cap)
    alive = np.zeros(cap, np.bool_)
    _plane(P, a, b, c, normals, offsets, 0)
    d_best, d = 0.0, -1
    for i in range(N):
        h = abs(_height(P, i, normals, offsets, 0))
        if h > d_best:
            d_best, d = h, i
    if d_best <= eps:
        return _FLAT
    if _height(P, d, normals, offsets, 0) > 0.0:                                # wind (a, b, c) away from d
        b, c = c, b
    corners = ((a, b, c), (a, d, b), (b, d, c), (c, d, a))                       # counter-clockwise from outside
    for f in range(4):
        fv[f, 0], fv[f, 1], fv[f, 2] = corners[f]
        if not _plane(P, fv[f, 0], fv[f, 1], fv[f, 2], normals, offsets, f):
            return _FLAT
        alive[f] = True
    for f in range(4):                                                          # neighbours: the shared edge reversed
        for k in range(3):
            u, v = fv[f, k], fv[f, (k + 1) % 3]
            for g in range(4):
                if g != f and ((fv[g, 0] == v and fv[g, 1] == u) or (fv[g, 1] == v and fv[g, 2] == u)
                               or (fv[g, 2] == v and fv[g, 0] == u)):
                    nb[f, k] = g
    inside = (P[a] + P[b] + P[c] + P[d]) / 4.0                                  # stays inside every later hull
    count = 4

    head = np.full(cap, -1, np.int64)                                           # each facet's outside points
    nxt = np.full(N, -1, np.int64)
    for i in range(N):
        if i == a or i == b or i == c or i == d:
            continue
        for f in range(4):
            if _height(P, i, normals, offsets, f) > eps:
                nxt[i] = head[f]
                head[f] = i
                break
    todo = np.empty(cap, np.int64)
    ntodo = 0
    for f in range(4):
        todo[ntodo] = f
        ntodo += 1
    seen = np.zeros(cap, np.int64)                                              # iteration stamp of seen facets
    stack = np.empty(cap, np.int64)
    h_u = np.empty(cap, np.int64)                                               # horizon: edge (u, v) of a seen
    h_v = np.empty(cap, np.int64)                                               # facet, and the unseen facet h
    h_f = np.empty(cap, np.int64)                                               # across it
    start_of = np.full(N, -1, np.int64)
    end_of = np.full(N, -1, np.int64)
    pending = np.empty(N, np.int64)
    stamp = 0
    while ntodo:
        ntodo -= 1
        f = todo[ntodo]
        if not alive[f] or head[f] < 0:
            continue
        p, far, i = -1, -1.0, head[f]                                           # the farthest outside point
        while i >= 0:
            h = _height(P, i, normals, offsets, f)
            if h > far:
                far, p = h, i
            i = nxt[i]
        stamp += 1
        seen[f] = stamp
        stack[0] = f
        nstack, nh, visible_top = 1, 0, 0
        while nstack:                                                           # the facets p sees, and their rim
            nstack -= 1
            g = stack[nstack]
            stack[cap - 1 - visible_top] = g                                    # keep the seen ones at the far end
            visible_top += 1
            for k in range(3):
                h = nb[g, k]
                if seen[h] == stamp:
                    continue
                if _height(P, p, normals, offsets, h) > eps:
                    seen[h] = stamp
                    stack[nstack] = h
                    nstack += 1
                else:
                    if nh >= cap:
                        return _FULL
                    h_u[nh], h_v[nh], h_f[nh] = fv[g, k], fv[g, (k + 1) % 3], h
                    nh += 1
            if nstack + visible_top + 3 >= cap:
                return _FULL
        npend = 0
        for s in range(visible_top):                                            # the seen facets' outside points
            g = stack[cap - 1 - s]
            alive[g] = False
            i = head[g]
            while i >= 0:
                if i != p:
                    pending[npend] = i
                    npend += 1
                i = nxt[i]
            head[g] = -1
        if nh < 3:                                                              # p sees every facet: numerically lost
            return _FAILED
        if count + nh > cap:
            return _FULL
        first = count
        for e in range(nh):                                                     # the fan from p to the horizon
            u, v, h = h_u[e], h_v[e], h_f[e]
            if start_of[u] >= 0 or end_of[v] >= 0:                              # the rim is not one simple loop
                return _FAILED
            nf = count
            count += 1
            fv[nf, 0], fv[nf, 1], fv[nf, 2] = u, v, p
            if not _plane(P, u, v, p, normals, offsets, nf):
                return _FAILED
            if (normals[nf, 0] * inside[0] + normals[nf, 1] * inside[1] + normals[nf, 2] * inside[2]
                    - offsets[nf]) >= 0.0:
                return _FAILED
            alive[nf] = True
            head[nf] = -1
            nb[nf, 0] = h
            for k in range(3):                                                  # h now borders the new facet
                if fv[h, k] == v and fv[h, (k + 1) % 3] == u:
                    nb[h, k] = nf
            start_of[u], end_of[v] = nf, nf
        for nf in range(first, count):
            u, v = fv[nf, 0], fv[nf, 1]
            nb[nf, 1], nb[nf, 2] = start_of[v], end_of[u]
            if nb[nf, 1] < 0 or nb[nf, 2] < 0:
                return _FAILED
        for nf in range(first, count):
            start_of[fv[nf, 0]], end_of[fv[nf, 1]] = -1, -1
        for s in range(npend):                  # to the first new facet they are outside of, else to a facet of
            i = pending[s]                      # the rim (a point that saw a facet p saw and one it did not also
            placed = False                      # sees a facet next to the rim), else inside now
            for nf in range(first, count):
                if _height(P, i, normals, offsets, nf) > eps:
                    nxt[i] = head[nf]
                    head[nf] = i
                    placed = True
                    break
            if placed:
                continue
            for e in range(nh):
                h = h_f[e]
                if _height(P, i, normals, offsets, h) > eps:
                    if head[h] < 0:                                             # not waiting yet: queue it
                        if ntodo >= cap:
                            return _FULL
                        todo[ntodo] = h
                        ntodo += 1
                    nxt[i] = head[h]
                    head[h] = i
                    break
        for nf in range(first, count):
            if head[nf] >= 0:
                if ntodo >= cap:
                    return _FULL
                todo[ntodo] = nf
                ntodo += 1
    for f in range(count):
        if alive[f]:
            mask[fv[f, 0]] = True
            mask[fv[f, 1]] = True
            mask[fv[f, 2]] = True
    return _OK
