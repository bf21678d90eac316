"""Geometry helpers shared by the SDK, training and evaluation (numpy + scipy; no torch).

Convention (one for the whole project):
    Points are row arrays ``[..., N, 3]``; rotation matrices act on column vectors: ``x_cam = R @ x_obj + t``, i.e.
    ``points_cam = points_obj @ R.T + t``. Quaternions ``(w, x, y, z)``, Hamilton product, unit norm, ``w >= 0`` when
    stored. Camera frame: OpenCV (x right, y down, z forward), metres. Depth: uint16 millimetres, 0 = invalid.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["quaternion_to_matrix", "matrix_to_quaternion", "rotation_angle_deg", "axis_angle_deg", "backproject",
           "farthest_point_order", "farthest_point_orders", "random_rotations", "rotation_between", "nearest_rotation"]


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


def _distance_tables(points: np.ndarray, caller: str) -> tuple:
    """Augmented float32 rows of the centred points for ``‖x − y‖² = [x, ‖x‖², 1] · [−2y, 1, ‖y‖²]``:
    (rows_t [5, P] with the points along the fast axis, cols [P, 5] whose row j is the query y_j)."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) == 0:
        raise ValueError(f"{caller}: no points")
    p = (p - p.mean(0)).astype(np.float32)                                      # [P, 3] centred
    sq = np.einsum("ij,ij->i", p, p)[:, None]                                   # [P, 1]
    one = np.ones((len(p), 1), np.float32)
    return np.ascontiguousarray(np.concatenate([p, sq, one], 1).T), np.concatenate([-2.0 * p, one, sq], 1)


def farthest_point_order(points: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """Greedy farthest-point sampling: indices [n] of ``points`` [P, 3], nested (its first k are FPS(k)).

    When ``n > P`` the order wraps around (indices repeat), so the model still receives N points. Each step is one
    float32 mat-vec of augmented rows ``[x, ‖x‖², 1] · [−2y, 1, ‖y‖²] = ‖x − y‖²`` (points centred first, which keeps
    the expansion exact to float32 precision), one in-place minimum and one argmax.
    """
    rows_t, cols = _distance_tables(points, "farthest_point_order")            # [5, P], [P, 5]
    P = cols.shape[0]
    m = min(int(n), P)
    idx = np.empty(m, dtype=np.int64)
    idx[0] = start
    d = cols[start] @ rows_t                                                    # [P] squared distance to the set
    t = np.empty_like(d)
    matmul, minimum, argmax = np.matmul, np.minimum, np.ndarray.argmax          # the loop is call-overhead bound
    for i in range(1, m):
        j = argmax(d)
        idx[i] = j
        matmul(cols[j], rows_t, out=t)
        minimum(d, t, out=d)
    if n > P:
        idx = np.resize(idx, int(n))
    return idx


def farthest_point_orders(points: np.ndarray, n: int, starts) -> np.ndarray:
    """``farthest_point_order`` from several starts at once: indices [S, n] of ``points`` [P, 3], row s the nested
    order from ``starts[s]``. One loop for all starts (each step a [S, 5] × [5, P] product), so S orders cost about
    what one does when P is a few thousand."""
    rows_t, cols = _distance_tables(points, "farthest_point_orders")           # [5, P], [P, 5]
    P = cols.shape[0]
    st = np.asarray(starts, dtype=np.int64).reshape(-1)                       # [S]
    if len(st) and (st.min() < 0 or st.max() >= P):
        raise ValueError(f"farthest_point_orders: starts must index the {P} points, got {st.tolist()}")
    m = min(int(n), P)
    idx = np.empty((len(st), m), dtype=np.int64)                                # [S, m]
    idx[:, 0] = st
    d = cols[st] @ rows_t                                                       # [S, P] squared distance to each set
    t = np.empty_like(d)
    for i in range(1, m):
        j = d.argmax(1)                                                         # [S]
        idx[:, i] = j
        np.matmul(cols[j], rows_t, out=t)
        np.minimum(d, t, out=d)
    if n > P:                                                                   # wrap each order, as above
        idx = np.stack([np.resize(r, int(n)) for r in idx]) if len(st) else np.empty((0, int(n)), np.int64)
    return idx


def nearest_rotation(M) -> np.ndarray:
    """[3, 3] closest rotation to ``M`` (SVD; e.g. a float32 model output or a product of rotations → exact SO(3))."""
    U, _, Vt = np.linalg.svd(np.asarray(M, np.float64))
    return U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt


def random_rotations(n: int, seed=None) -> np.ndarray:
    """``n`` uniform random rotations [n, 3, 3] (scipy, seeded)."""
    return Rotation.random(n, random_state=seed).as_matrix()


def rotation_between(a, b) -> np.ndarray:
    """Smallest rotation taking direction ``a`` onto direction ``b`` (any lengths > 0): [3] and [3] → [3, 3], or
    broadcast over leading axes ([..., 3] → [..., 3, 3]); for opposite directions, the half turn about an axis
    perpendicular to ``a``."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    a, b = np.broadcast_arrays(a / np.linalg.norm(a, axis=-1, keepdims=True),
                               b / np.linalg.norm(b, axis=-1, keepdims=True))           # [..., 3] unit
    v, c = np.cross(a, b), np.einsum("...i,...i->...", a, b)                           # [..., 3], [...]
    V = np.zeros(v.shape + (3,))
    V[..., 0, 1], V[..., 0, 2], V[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    V = V - np.swapaxes(V, -1, -2)                                                      # [..., 3, 3] cross matrices
    R = np.eye(3) + V + V @ V / np.maximum(1.0 + c, 1e-12)[..., None, None]             # [..., 3, 3]
    opposite = c < -1.0 + 1e-9
    if np.any(opposite):                                                                # half turns: rare
        ao = a[opposite]                                                                # [K, 3]
        p = np.cross(ao, np.eye(3)[np.argmin(np.abs(ao), axis=-1)])
        p /= np.linalg.norm(p, axis=-1, keepdims=True)
        R[opposite] = 2.0 * np.einsum("ki,kj->kij", p, p) - np.eye(3)
    return R
