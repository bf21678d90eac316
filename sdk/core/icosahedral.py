"""The icosahedral rotation group I (60 rotations) and the constant tables built on it.

Convention:
    Rotation matrices act on column vectors (``x' = R @ x``); points are row arrays ``[..., N, 3]`` so a rotation is
    applied as ``x @ R.T``. Quaternions are ``(w, x, y, z)``, Hamilton product, unit norm, ``w >= 0``.

Construction (documented, no trimesh at run time):
    ``_ANCHOR_QUATERNIONS`` holds the 60 rotations of the reference implementation (vgtk's ``sphere12.ply`` anchors,
    normalised so that index 29 is the identity) as 6-decimal quaternions (spec Appendix A). At import they are turned
    into matrices, projected onto SO(3) and then *polished*: each element is replaced by the chordal mean of all
    products ``A_i @ A_j`` that the Cayley table says equal it. Three rounds make the set closed under products to
    float64 precision (≈1e-15), so every table derived from it is exact.

Tables (all numpy, int64 where indices):
    ``ANCHORS``            [60, 3, 3]  the rotations; ``IDENTITY_INDEX`` = 29.
    ``CAYLEY``             [60, 60]    ``CAYLEY[i, j] = index(A_i @ A_j)``.
    ``INVERSE``            [60]        ``INVERSE[i] = index(A_i.T)``.
    ``INTRA_GENERATORS``   [12]        the fixed set H of the intra (group) convolution (spec §1.2).
    ``INTRA_NEIGHBOURS``   [60, 12]    ``INTRA_NEIGHBOURS[g, k] = CAYLEY[g, H[k]]`` (right multiplication by H).
    ``VERTICES``           [12, 3]     unit icosahedron vertices (the 5-fold axes, both signs).
    ``VERTEX_PERMUTATION`` [60, 12]    ``VERTICES[VERTEX_PERMUTATION[g, v]] = A_g @ VERTICES[v]``.
    ``KERNEL_POINTS_24``   [24, 3]     the reference's ``kpsphere24`` kernel points (index 0 = centre), raw units.
    ``KERNEL_POINTS_13``   [13, 3]     centre + the 12 vertices (an icosahedrally symmetric kernel, E2PN-style).
    ``VERTEX_CLASS``       [12, 12]    class of vertex u seen from vertex v: 0 same, 1 neighbour ring (dot 1/√5),
                                       2 far ring (dot −1/√5), 3 antipode. Rotations preserve it (the quotient
                                       features' kernels share weights within a class).
    ``ROTATION_VERTEX_PAIR`` [60, 2]   ``VERTEX_PERMUTATION[g, (0, n0)]`` with n0 a neighbour of vertex 0: the ordered
                                       adjacent vertex pair that rotation g carries (0, n0) to; unique per rotation,
                                       so a pair of vertex features lifts back to the 60 rotations equivariantly.
"""
from __future__ import annotations

import numpy as np

from equipose.core.geometry import matrix_to_quaternion, quaternion_to_matrix

__all__ = [
    "NUM_ROTATIONS", "IDENTITY_INDEX", "ANCHORS", "ANCHOR_QUATERNIONS", "CAYLEY", "INVERSE", "INTRA_GENERATORS",
    "INTRA_NEIGHBOURS", "VERTICES", "VERTEX_PERMUTATION", "KERNEL_POINTS_24", "KERNEL_POINTS_13", "kernel_points",
    "VERTEX_CLASS", "ROTATION_VERTEX_PAIR", "nearest_anchor", "rotation_index",
]

NUM_ROTATIONS = 60
IDENTITY_INDEX = 29

# (w, x, y, z) per anchor index 0..59 (spec Appendix A; vgtk anchor order).
_ANCHOR_QUATERNIONS = """
0.309017 -0.755761 0.500000 -0.288676  0.809017 -0.110264 0.500000 0.288675  0.500000 0.645497 0.000000 0.577350
0.500000 -0.288675 0.809017 -0.110264  0.500000 0.288675 0.500000 0.645497  0.000000 -0.577350 0.309017 -0.755761
0.500000 0.288675 0.809017 0.110264  0.000000 0.577350 0.309017 0.755761  0.500000 -0.288675 0.500000 -0.645497
0.309017 0.755761 0.500000 0.288676  0.500000 -0.645497 0.000000 -0.577350  0.809017 0.110264 0.500000 -0.288675
0.000000 0.934172 -0.000000 0.356823  0.809017 -0.467086 0.309017 -0.178411  0.809017 0.467086 0.309017 0.178411
0.309017 0.755761 -0.500000 0.288675  0.500000 -0.645497 0.500000 0.288675  0.809017 0.110264 0.000000 0.577350
0.000000 0.356822 -0.809017 0.467086  0.309017 -0.178411 0.809017 0.467086  0.309017 0.178411 0.000000 0.934172
0.309017 0.178411 0.809017 -0.467086  0.000000 -0.356822 -0.809017 -0.467086  0.309017 -0.178411 0.000000 -0.934172
0.500000 0.645497 0.500000 -0.288675  0.309017 -0.755761 -0.500000 -0.288675  0.809017 -0.110264 0.000000 -0.577350
0.500000 0.866025 0.000000 0.000000  0.500000 -0.866025 -0.000000 -0.000000  1.000000 0.000000 0.000000 0.000000
0.000000 0.934172 -0.309017 -0.178411  0.809017 -0.467086 0.000000 0.356822  0.809017 0.467086 -0.309017 0.178411
0.000000 0.577350 -0.809017 -0.110264  0.500000 -0.288675 0.309017 0.755761  0.500000 0.288675 -0.500000 0.645497
0.000000 0.000000 1.000000 0.000000  0.000000 -0.000000 0.500000 0.866025  0.000000 0.000000 -0.500000 0.866025
0.000000 -0.577350 -0.809017 0.110264  0.500000 -0.288675 -0.500000 -0.645497  0.500000 0.288675 0.309017 -0.755761
0.000000 -0.934172 -0.309017 0.178411  0.809017 -0.467086 -0.309017 -0.178411  0.809017 0.467086 0.000000 -0.356822
0.500000 0.645497 -0.500000 -0.288675  0.309017 -0.755761 -0.000000 0.577350  0.809017 -0.110264 -0.500000 0.288675
0.500000 0.288675 -0.809017 0.110264  0.000000 0.577350 -0.500000 -0.645497  0.500000 -0.288676 -0.309017 0.755761
0.309017 -0.178411 -0.809017 0.467086  0.309017 0.178411 -0.809017 -0.467086  0.000000 -0.356823 -0.000000 0.934172
0.000000 -0.577350 -0.500000 0.645497  0.500000 -0.288675 -0.809017 -0.110264  0.500000 0.288676 -0.309017 -0.755761
0.309017 0.755761 -0.000000 -0.577350  0.500000 -0.645497 -0.500000 0.288675  0.809017 0.110264 -0.500000 -0.288675
"""

# The intra-convolution generator set H (spec §1.2): column 9 is the identity, 10/11 are the own-face ±120° spins.
INTRA_GENERATORS = np.array([44, 31, 32, 13, 42, 43, 30, 14, 12, 29, 28, 27], dtype=np.int64)

# kpsphere24 raw kernel points (spec Appendix C); scale by (0.7 * radius) / max-norm before use.
_KERNEL_24 = """
0.0000 0.0000 0.0000  0.6299 -0.2149 -0.7423  -0.3022 0.7119 -0.6461  -0.2966 -0.9471 -0.1752
0.2247 0.2260 0.9405  -0.9917 0.0428 0.1434  0.5258 0.7599 0.4020  -0.2035 -0.0206 -0.9718
0.3777 0.4709 -0.8007  0.0201 -0.8949 0.4631  0.1504 0.9692 -0.1638  -0.6206 0.2209 0.7483
-0.7326 -0.4753 -0.4757  -0.1841 0.7913 0.5883  -0.7168 -0.5765 0.3743  0.5800 -0.4954 0.6381
0.0465 -0.6561 -0.7571  0.8635 0.1413 0.4999  0.5038 -0.8428 -0.1487  -0.6553 0.7446 0.0504
0.9561 -0.2905 -0.0871  -0.8158 0.2253 -0.5471  -0.2005 -0.3558 0.9158  0.8413 0.4655 -0.2484
"""


def _project_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (chordal L2) to each [..., 3, 3] matrix."""
    U, _, Vt = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., :, 2] *= d[..., None]
    return U @ Vt


def _nearest(R: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Index of the nearest element of ``table`` [G,3,3] to each rotation in ``R`` [...,3,3] (max trace of R_g^T R)."""
    tr = np.einsum("gij,...ij->...g", table, R)
    return tr.argmax(-1)


def _build():
    raw = np.array(_ANCHOR_QUATERNIONS.split(), dtype=np.float64).reshape(NUM_ROTATIONS, 4)
    A = _project_so3(quaternion_to_matrix(raw))
    for _ in range(3):  # polish: each element = chordal mean of all products that equal it
        prod = np.einsum("iab,jbc->ijac", A, A)                      # [60, 60, 3, 3]
        cay = _nearest(prod, A)                                       # [60, 60]
        acc = np.zeros_like(A)
        np.add.at(acc, cay.reshape(-1), prod.reshape(-1, 3, 3))
        A = _project_so3(acc)
    cay = _nearest(np.einsum("iab,jbc->ijac", A, A), A)
    inv = _nearest(np.swapaxes(A, 1, 2), A)
    return A, cay.astype(np.int64), inv.astype(np.int64)


ANCHORS, CAYLEY, INVERSE = _build()
ANCHORS.setflags(write=False)
ANCHOR_QUATERNIONS = matrix_to_quaternion(ANCHORS)
INTRA_NEIGHBOURS = CAYLEY[:, INTRA_GENERATORS]


def _build_vertices():
    # The 5-fold axes: rotation axes of the 12 elements with angle 72°, both signs (12 vertices).
    ang = np.degrees(np.arccos(np.clip((np.trace(ANCHORS, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    axes = []
    for R in ANCHORS[np.abs(ang - 72.0) < 1e-6]:
        w, v = np.linalg.eig(R)
        axis = np.real(v[:, np.argmin(np.abs(w - 1))])
        axis /= np.linalg.norm(axis)
        if not any(abs(abs(axis @ a) - 1) < 1e-9 for a in axes):
            axes.append(axis)
    axes = np.array(sorted(axes, key=lambda a: tuple(np.round(-np.sign(a[np.flatnonzero(np.abs(a) > 1e-9)[0]]) * a, 9))))
    # Orient each axis so its first non-zero coordinate is positive; then append the antipodes in the same order.
    axes = np.array([a if a[np.flatnonzero(np.abs(a) > 1e-9)[0]] > 0 else -a for a in axes])
    verts = np.concatenate([axes, -axes], 0)                          # [12, 3]
    moved = np.einsum("gij,vj->gvi", ANCHORS, verts)                  # [60, 12, 3]
    perm = np.argmax(np.einsum("gvi,ui->gvu", moved, verts), -1)      # [60, 12]
    return verts, perm.astype(np.int64)


VERTICES, VERTEX_PERMUTATION = _build_vertices()


def _build_vertex_tables():
    dots = VERTICES @ VERTICES.T                                      # [12, 12] cosines: 1, ±1/√5, −1
    cls = np.select([dots > 0.99, dots > 0.0, dots > -0.99], [0, 1, 2], 3).astype(np.int64)
    n0 = int(np.flatnonzero(cls[0] == 1)[0])
    pair = VERTEX_PERMUTATION[:, [0, n0]]                             # [60, 2]
    assert len({tuple(p) for p in pair}) == NUM_ROTATIONS             # the action on adjacent pairs is free
    return cls, pair.astype(np.int64)


VERTEX_CLASS, ROTATION_VERTEX_PAIR = _build_vertex_tables()

KERNEL_POINTS_24 = np.array(_KERNEL_24.split(), dtype=np.float64).reshape(24, 3)
KERNEL_POINTS_13 = np.concatenate([np.zeros((1, 3)), VERTICES], 0)


def kernel_points(kind: int, radius: float) -> np.ndarray:
    """Kernel points [K, 3] scaled so the farthest lies at ``radius`` (model units). ``kind`` ∈ {24, 13}."""
    if kind == 24:
        raw = KERNEL_POINTS_24
    elif kind == 13:
        raw = KERNEL_POINTS_13
    else:
        raise ValueError(f"kernel point set must be 24 or 13, got {kind}")
    return raw * (radius / np.linalg.norm(raw, axis=1).max())


def nearest_anchor(R: np.ndarray) -> np.ndarray:
    """Index of the nearest group rotation for each ``R`` [..., 3, 3] (geodesic distance)."""
    return _nearest(np.asarray(R, dtype=np.float64), ANCHORS)


def rotation_index(R: np.ndarray, atol: float = 1e-4) -> int:
    """Index of ``R`` [3, 3] in the group; ``ValueError`` if it is not a group element (within ``atol``)."""
    i = int(nearest_anchor(R))
    if not np.allclose(ANCHORS[i], R, atol=atol):
        raise ValueError("rotation is not an element of the icosahedral group")
    return i
