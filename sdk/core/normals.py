"""Point normals of a cloud: the smallest principal direction of each point's k nearest neighbours (PCA), compiled.

Convention: ``points`` [N, 3] any units, any frame; normals [N, 3] unit vectors in that frame, sign arbitrary.
Exact neighbours by a dense scan (O(N²)): meant for a model input's few hundred points or a template of about a
thousand, computed once.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from equipose.core.eigen import top_eigenvector

__all__ = ["point_normals"]


def point_normals(points, k: int = 12) -> np.ndarray:
    """[N, 3] unit normals (smallest principal direction of each point's k nearest neighbours, itself included; sign
    arbitrary). One compiled pass: exact neighbours by a dense scan (a model input's N ≤ a few hundred points)."""
    P = np.ascontiguousarray(points, np.float64)                             # [N, 3]
    out = np.empty_like(P)
    _normals(P, min(int(k), len(P)), out)
    return out


@njit(cache=True, nogil=True)
def _normals(P, k, out) -> None:
    """``out`` [N, 3] ← the normal of each point of ``P`` [N, 3] from its ``k`` nearest points (itself included)."""
    N = len(P)
    near_d, near_i = np.empty(k), np.empty(k, np.int64)                     # the k nearest so far, ascending
    C = np.empty((3, 3))
    X, Y, Z = P[:, 0].copy(), P[:, 1].copy(), P[:, 2].copy()                # [N] each: contiguous, vectorised rows
    row = np.empty(N)                                                         # [N] squared distances from point i
    for i in range(N):
        xi, yi, zi = X[i], Y[i], Z[i]
        for j in range(N):
            row[j] = (X[j] - xi) ** 2 + (Y[j] - yi) ** 2 + (Z[j] - zi) ** 2
        m = 0                                                                 # neighbours held
        for j in range(N):
            d = row[j]
            if m == k and d >= near_d[k - 1]:
                continue
            pos = m if m < k else k - 1                                       # insertion into the sorted list
            while pos > 0 and near_d[pos - 1] > d:
                near_d[pos], near_i[pos] = near_d[pos - 1], near_i[pos - 1]
                pos -= 1
            near_d[pos], near_i[pos] = d, j
            if m < k:
                m += 1
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
        out[i] = top_eigenvector(C)
