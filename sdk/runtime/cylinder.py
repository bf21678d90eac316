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

from equipose.core.normals import point_normals
from equipose.core.revolution import SIDE_BAND

__all__ = ["point_normals", "cylinder_axis", "refine_side_axis", "SIDE_BAND"]


def _cost(normals, axis) -> float:
    c2 = (normals @ axis) ** 2
    return float(np.mean(np.minimum(c2, 1.0 - c2)))


SWITCH_ANGLE_DEG = 45.0     # only an axis this far from the network's can replace it (the network's is more precise)
SWITCH_RATIO = 0.85         # ... and only when its cost is below this fraction of the network axis' cost


def cylinder_axis(points, axis0, k: int = 12, normals=None, ratio: float = SWITCH_RATIO, candidates=()) -> tuple:
    """(axis [3], cost of ``axis0``, cost of the chosen axis) for the points of one cylinder-like object: the network's
    ``axis0`` unless a principal direction of the normals, or one of the ``candidates`` (unit [3] directions, e.g. the
    normal of the table it stands on), ≥ ``SWITCH_ANGLE_DEG`` away fits the cylinder pattern clearly better (cost <
    ``ratio`` × cost of ``axis0``, default ``SWITCH_RATIO``): the lying / upright confusion of squat tins.
    ``normals`` [N, 3]: the points' unit normals when already computed (else from the ``k`` nearest neighbours)."""
    n = point_normals(points, k) if normals is None else np.asarray(normals, np.float64)
    a0 = np.asarray(axis0, np.float64) / np.linalg.norm(axis0)
    _, vecs = np.linalg.eigh(n.T @ n)                                        # principal directions of the normals
    options = list(vecs.T) + [np.asarray(c, np.float64) / np.linalg.norm(c) for c in candidates]
    far = [v for v in options if abs(float(v @ a0)) < np.cos(np.radians(SWITCH_ANGLE_DEG))]
    c0 = _cost(n, a0)
    if not far:
        return a0, c0, c0
    costs = [_cost(n, v) for v in far]
    best = far[int(np.argmin(costs))]
    if min(costs) >= ratio * c0:
        return a0, c0, c0
    return (best if best @ a0 >= 0 else -best), c0, min(costs)


SIDE_MIN_POINTS = 20        # fewer side normals than this: the axis is left as it is


def refine_side_axis(normals, axis, band: float = SIDE_BAND, iters: int = 3) -> np.ndarray:
    """The axis [3] that the side normals of a body of revolution are most perpendicular to, started from ``axis``
    (unit [3], its sign kept): ``iters`` rounds of taking the normals [N, 3] within ``band`` of perpendicular to the
    current axis and the least-variance direction of their scatter (smallest eigenvector of Σ n nᵀ). Exact for a
    straight side; a tapered side seen from one side biases it (about 7° for normals 6° off perpendicular with half
    the side visible). Used for open cylinders (cups and mugs), whose network axis is the less precise one
    (docs/results/confidence/README.md, v0.34)."""
    n = np.asarray(normals, np.float64)
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    for _ in range(iters):
        side = n[np.abs(n @ a) < band]                                          # [S, 3]
        if len(side) < SIDE_MIN_POINTS:
            break
        _, vecs = np.linalg.eigh(side.T @ side)
        b = vecs[:, 0]
        a = b if b @ a >= 0 else -b
    return a
