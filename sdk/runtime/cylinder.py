"""The cylinder stage of models whose category is a cylinder (metadata ``shape_prior`` "cylinder": cans, tins, tubes).

A network trained on cans tends to put the axis along the longest extent, so squat tins (height < diameter) come out
lying. On a cylinder every surface normal is either perpendicular to the axis (the side) or parallel to it (the lids);
the stage scores axes by how well the normals follow that pattern — cost = mean over points of min((n·a)², 1 − (n·a)²)
— and replaces the network's axis by a principal direction of the normals far from it when that one fits clearly
better, turning the pose onto it.

Convention: ``model_points`` [N, 3] model units, centred camera frame (rotation-free, so any frame works); normals from
the ``k`` nearest neighbours (PCA). Axes are unit [3] vectors; the axis sign is kept from the network's.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from equipose.core.eigen import top_eigenvector

__all__ = ["point_normals", "cylinder_axis"]


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
    for i in range(N):
        m = 0                                                                 # neighbours held
        for j in range(N):
            d = (P[j, 0] - P[i, 0]) ** 2 + (P[j, 1] - P[i, 1]) ** 2 + (P[j, 2] - P[i, 2]) ** 2
            if m == k and d >= near_d[k - 1]:
                continue
            pos = m if m < k else k - 1                                       # insertion into the sorted list
            while pos > 0 and near_d[pos - 1] > d:
                if pos < k:
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


def _cost(normals, axis) -> float:
    c2 = (normals @ axis) ** 2
    return float(np.mean(np.minimum(c2, 1.0 - c2)))


SWITCH_ANGLE_DEG = 45.0     # only an axis this far from the network's can replace it (the network's is more precise)
SWITCH_RATIO = 0.85         # ... and only when its cost is below this fraction of the network axis' cost


def cylinder_axis(points, axis0, k: int = 12) -> tuple:
    """(axis [3], cost of ``axis0``, cost of the chosen axis) for the points of one cylinder-like object: the network's
    ``axis0`` unless a principal direction of the normals ≥ ``SWITCH_ANGLE_DEG`` away fits the cylinder pattern
    clearly better (cost < ``SWITCH_RATIO`` × cost of ``axis0``): the lying / upright confusion of squat tins."""
    n = point_normals(points, k)
    a0 = np.asarray(axis0, np.float64) / np.linalg.norm(axis0)
    _, vecs = np.linalg.eigh(n.T @ n)                                        # principal directions of the normals
    far = [v for v in vecs.T if abs(float(v @ a0)) < np.cos(np.radians(SWITCH_ANGLE_DEG))]
    c0 = _cost(n, a0)
    if not far:
        return a0, c0, c0
    costs = [_cost(n, v) for v in far]
    best = far[int(np.argmin(costs))]
    if min(costs) >= SWITCH_RATIO * c0:
        return a0, c0, c0
    return (best if best @ a0 >= 0 else -best), c0, min(costs)
