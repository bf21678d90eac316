"""Geometry helpers shared by the SDK, training and evaluation (numpy + scipy, numba loops; no torch).

Convention (one for the whole project):
    Points are row arrays ``[..., N, 3]``; rotation matrices act on column vectors: ``x_cam = R @ x_obj + t``, i.e.
    ``points_cam = points_obj @ R.T + t``. Quaternions ``(w, x, y, z)``, Hamilton product, unit norm, ``w >= 0`` when
    stored. Camera frame: OpenCV (x right, y down, z forward), metres. Depth: uint16 millimetres, 0 = invalid.
"""
from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial.transform import Rotation

from equipose.core.parallel import run_parts, split_ranges, workers

__all__ = ["quaternion_to_matrix", "matrix_to_quaternion", "rotation_angle_deg", "axis_angle_deg", "backproject",
           "farthest_point_order", "farthest_point_orders", "random_rotations", "rotation_between", "nearest_rotation",
           "cross"]


def quaternion_to_matrix(q) -> np.ndarray:
    """(w, x, y, z) [..., 4] → rotation [..., 3, 3] (normalised first)."""
    q = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat(q[..., [1, 2, 3, 0]].reshape(-1, 4)).as_matrix().reshape(q.shape[:-1] + (3, 3))


def matrix_to_quaternion(R) -> np.ndarray:
    """Rotation [..., 3, 3] → (w, x, y, z) [..., 4] with w ≥ 0."""
    R = np.asarray(R, dtype=np.float64)
    q = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()[:, [3, 0, 1, 2]]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.reshape(R.shape[:-2] + (4,))


def rotation_angle_deg(R1, R2) -> np.ndarray:
    """Geodesic angle between rotations [..., 3, 3], degrees: acos((tr(R1 R2ᵀ) − 1) / 2)."""
    R1, R2 = np.asarray(R1, np.float64), np.asarray(R2, np.float64)
    c = (np.einsum("...ij,...ij->...", R1, R2) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def axis_angle_deg(a, b, unsigned: bool = False) -> np.ndarray:
    """Angle between direction vectors [..., 3], degrees; ``unsigned`` treats a and −a as the same axis."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    c = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1) + 1e-12)
    if unsigned:
        c = np.abs(c)
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def backproject(depth_m: np.ndarray, K: np.ndarray, mask: np.ndarray | None = None) -> tuple:
    """Pinhole back-projection of valid pixels (depth > 0, finite, inside ``mask``).

    Args:
        depth_m: [H, W] float depth in metres (0 or non-finite = invalid).
        K: [3, 3] intrinsics (pixel centres at integer coordinates, OpenCV convention).
        mask: optional [H, W] bool.
    Returns:
        (points [N, 3] float32 metres in the camera frame, pixels [N, 2] int (row, col)).
    """
    valid = np.isfinite(depth_m) & (depth_m > 0)
    if mask is not None:
        valid &= mask
    rows, cols = np.nonzero(valid)                                          # [N], [N]
    z = depth_m[rows, cols].astype(np.float64)
    x = (cols - K[0, 2]) * z / K[0, 0]
    y = (rows - K[1, 2]) * z / K[1, 1]
    return np.stack([x, y, z], 1).astype(np.float32), np.stack([rows, cols], 1)


@njit(cache=True, nogil=True)
def _farthest_orders(p, n, starts):
    """FPS loop of ``farthest_point_orders``: ``p`` [3, P] float32 centred (coordinates along the fast axis),
    ``starts`` [S] → indices [S, n ≤ P]. Each step writes the float32 squared distances to the newest point, then
    updates every point's distance to the set and takes the largest on their int32 bit patterns (non-negative
    floats order as their bits), two loops the compiler vectorises; among equally far points the first wins."""
    P, S = p.shape[1], len(starts)
    px, py, pz = p[0], p[1], p[2]                                               # [P] each
    idx = np.empty((S, n), np.int64)
    new = np.empty(P, np.float32)
    new_bits = new.view(np.int32)
    d = np.empty(P, np.int32)                                                   # bits of the distance to the set
    for s in range(S):
        j = starts[s]
        idx[s, 0] = j
        d[:] = 0x7F7FFFFF                                                       # the largest finite float32
        for k in range(1, n):
            x, y, z = px[j], py[j], pz[j]
            for i in range(P):
                dx, dy, dz = px[i] - x, py[i] - y, pz[i] - z
                new[i] = dx * dx + dy * dy + dz * dz
            best = np.int32(-1)
            for i in range(P):
                e = d[i] if d[i] < new_bits[i] else new_bits[i]
                d[i] = e
                best = e if e > best else best
            j = 0
            while d[j] != best:
                j += 1
            idx[s, k] = j
    return idx


def _centred_columns(points, caller: str) -> np.ndarray:
    """[3, P] float32 of the centred ``points`` [P, 3] (centring keeps float32 distances exact to its precision)."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0:
        raise ValueError(f"{caller}: points must be [P ≥ 1, 3], got {p.shape}")
    return np.ascontiguousarray((p - p.mean(0)).T, np.float32)


def farthest_point_order(points: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """Greedy farthest-point sampling: indices [n] of ``points`` [P, 3], nested (its first k are FPS(k)).

    When ``n > P`` the order wraps around (indices repeat), so the model still receives N points. Distances are
    float32 on the centred points; among equally far points the first wins.
    """
    return farthest_point_orders(points, n, [start])[0]


def farthest_point_orders(points: np.ndarray, n: int, starts) -> np.ndarray:
    """``farthest_point_order`` from several starts: indices [S, n] of ``points`` [P, 3], row s the nested order
    from ``starts[s]``. The starts run in ``equipose.core.parallel.workers()`` parts side by side."""
    p = _centred_columns(points, "farthest_point_orders")                     # [3, P]
    P = p.shape[1]
    st = np.asarray(starts, dtype=np.int64).reshape(-1)                       # [S]
    if len(st) and (st.min() < 0 or st.max() >= P):
        raise ValueError(f"farthest_point_orders: starts must index the {P} points, got {st.tolist()}")
    m = min(int(n), P)
    outs = run_parts(_farthest_orders, [(p, m, st[a:b]) for a, b in split_ranges(len(st), workers())])  # (nogil)
    idx = outs[0] if len(outs) == 1 else np.concatenate(outs)                 # [S, m]
    if n > P:                                                                   # wrap each order
        idx = np.stack([np.resize(r, int(n)) for r in idx]) if len(st) else np.empty((0, int(n)), np.int64)
    return idx


def nearest_rotation(M) -> np.ndarray:
    """[3, 3] closest rotation to ``M`` (SVD; e.g. a float32 model output or a product of rotations → exact SO(3))."""
    U, _, Vt = np.linalg.svd(np.asarray(M, np.float64))
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def random_rotations(n: int, seed=None) -> np.ndarray:
    """``n`` uniform random rotations [n, 3, 3] (scipy, seeded)."""
    return Rotation.random(n, random_state=seed).as_matrix()


def cross(a, b) -> np.ndarray:
    """``a × b`` over the last axis ([..., 3], broadcast): numpy's ``np.cross`` with the same arithmetic, without its
    per-call overhead (about 50 µs per call on 3-vectors here, against 3 µs)."""
    a, b = np.asarray(a), np.asarray(b)
    a0, a1, a2, b0, b1, b2 = a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1], b[..., 2]
    return np.stack(np.broadcast_arrays(a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0), -1)


def rotation_between(a, b) -> np.ndarray:
    """Smallest rotation taking direction ``a`` onto direction ``b`` (any lengths > 0): [3] and [3] → [3, 3], or
    broadcast over leading axes ([..., 3] → [..., 3, 3]); for opposite directions, the half turn about an axis
    perpendicular to ``a``."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    a, b = np.broadcast_arrays(a / np.linalg.norm(a, axis=-1, keepdims=True),
                               b / np.linalg.norm(b, axis=-1, keepdims=True))           # [..., 3] unit
    v, c = cross(a, b), np.einsum("...i,...i->...", a, b)                              # [..., 3], [...]
    V = np.zeros(v.shape + (3,))
    V[..., 0, 1], V[..., 0, 2], V[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    V = V - np.swapaxes(V, -1, -2)                                                      # [..., 3, 3] cross matrices
    R = np.eye(3) + V + V @ V / np.maximum(1.0 + c, 1e-12)[..., None, None]             # [..., 3, 3]
    opposite = c < -1.0 + 1e-9
    if np.any(opposite):                                                                # half turns: rare
        ao = a[opposite]                                                                # [K, 3]
        p = cross(ao, np.eye(3)[np.argmin(np.abs(ao), axis=-1)])
        p /= np.linalg.norm(p, axis=-1, keepdims=True)
        R[opposite] = 2.0 * np.einsum("ki,kj->kij", p, p) - np.eye(3)
    return R
