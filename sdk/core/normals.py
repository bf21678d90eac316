"""Point normals of a cloud: the smallest principal direction of each point's k nearest neighbours (PCA), compiled.

Convention: ``points`` [N, 3] any units, any frame; normals [N, 3] unit vectors in that frame, sign arbitrary.
Exact neighbours on a uniform grid (about two points per cell, rings of cells searched outward).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from equipose.core.eigen import top_eigenvector_into

__all__ = ["point_normals"]


def point_normals(points, k: int = 12) -> np.ndarray:
    """[N, 3] unit normals (smallest principal direction of each point's k nearest neighbours, itself included; sign
    arbitrary). One compiled pass: exact neighbours on a uniform grid."""
    P = np.ascontiguousarray(points, np.float64)                             # [N, 3]
    out = np.empty_like(P)
    _normals(P, min(int(k), len(P)), out)
    return out


@njit(cache=True, nogil=True)
def _normals(P, k, out) -> None:
    """``out`` [N, 3] ← the normal of each point of ``P`` [N, 3] from its ``k`` nearest points (itself included).

    The neighbours are the k smallest by (squared distance, index), in that order: what a scan of every point in
    index order keeps. They are found on a uniform grid of about two points per cell, ring by ring of cells around
    the point's own, until no point outside the rings can come nearer than the k-th held."""
    N = len(P)
    near_d, near_i = np.empty(k), np.empty(k, np.int64)                     # the k nearest so far, by (d, index)
    C, V = np.empty((3, 3)), np.empty((3, 3))                               # scatter, its eigenvectors
    lo = np.empty(3)
    for a in range(3):
        lo[a] = P[:, a].min()
    span = max(P[:, 0].max() - lo[0], P[:, 1].max() - lo[1], P[:, 2].max() - lo[2], 1e-12)
    G = max(1, int(np.ceil((N / 2.0) ** (1.0 / 3.0))))                        # cells per axis
    h = span / G * (1.0 + 1e-9)                                               # cell edge; the far face excluded
    cell = np.empty((N, 3), np.int64)
    start = np.zeros(G * G * G + 1, np.int64)
    for i in range(N):                                                        # counting sort by cell, index order
        for a in range(3):
            cell[i, a] = min(int((P[i, a] - lo[a]) / h), G - 1)
        start[(cell[i, 0] * G + cell[i, 1]) * G + cell[i, 2] + 1] += 1
    for c in range(G * G * G):
        start[c + 1] += start[c]
    items, fill = np.empty(N, np.int64), start[:-1].copy()
    for i in range(N):
        c = (cell[i, 0] * G + cell[i, 1]) * G + cell[i, 2]
        items[fill[c]] = i
        fill[c] += 1
    for i in range(N):
        xi, yi, zi = P[i, 0], P[i, 1], P[i, 2]
        cx, cy, cz = cell[i, 0], cell[i, 1], cell[i, 2]
        gap = np.inf                                                          # to the nearest face of its cell
        for a in range(3):
            off = P[i, a] - lo[a] - cell[i, a] * h
            gap = min(gap, off, h - off)
        m = 0                                                                 # neighbours held
        for r in range(G):
            for gx in range(max(cx - r, 0), min(cx + r, G - 1) + 1):
                for gy in range(max(cy - r, 0), min(cy + r, G - 1) + 1):
                    for gz in range(max(cz - r, 0), min(cz + r, G - 1) + 1):
                        if max(abs(gx - cx), abs(gy - cy), abs(gz - cz)) != r:
                            continue                                          # an inner ring: already visited
                        c = (gx * G + gy) * G + gz
                        for s in range(start[c], start[c + 1]):
                            j = items[s]
                            d = (P[j, 0] - xi) ** 2 + (P[j, 1] - yi) ** 2 + (P[j, 2] - zi) ** 2
                            if m == k and (d > near_d[k - 1] or (d == near_d[k - 1] and j > near_i[k - 1])):
                                continue
                            pos = m if m < k else k - 1                       # insertion into the sorted list
                            while pos > 0 and (near_d[pos - 1] > d or (near_d[pos - 1] == d and near_i[pos - 1] > j)):
                                near_d[pos], near_i[pos] = near_d[pos - 1], near_i[pos - 1]
                                pos -= 1
                            near_d[pos], near_i[pos] = d, j
                            if m < k:
                                m += 1
            reach = (r * h + max(gap, 0.0)) * (1.0 - 1e-9)                    # every point beyond the rings so far
            if m == k and near_d[k - 1] < reach * reach:
                break
        c0, c1, c2 = 0.0, 0.0, 0.0
        for a in range(k):
            c0 += P[near_i[a], 0]
            c1 += P[near_i[a], 1]
            c2 += P[near_i[a], 2]
        c0, c1, c2 = c0 / k, c1 / k, c2 / k
        C[:] = 0.0
        for a in range(k):
            q0, q1, q2 = P[near_i[a], 0] - c0, P[near_i[a], 1] - c1, P[near_i[a], 2] - c2
            C[0, 0] += q0 * q0
            C[0, 1] += q0 * q1
            C[0, 2] += q0 * q2
            C[1, 1] += q1 * q1
            C[1, 2] += q1 * q2
            C[2, 2] += q2 * q2
        C[1, 0], C[2, 0], C[2, 1] = C[0, 1], C[0, 2], C[1, 2]
        tr = C[0, 0] + C[1, 1] + C[2, 2]                                      # the smallest direction of C is the
        for a in range(3):                                                    # largest of tr·I − C
            for b in range(3):
                C[a, b] = (tr if a == b else 0.0) - C[a, b]
        b = top_eigenvector_into(C, V)
        for a in range(3):
            out[i, a] = V[a, b]
