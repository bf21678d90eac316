"""ICP-60 + template baseline (the paper's "ICP + template shape"): point-to-point ICP from the 60 icosahedral
rotations, best final residual wins.

Convention:
    ``observed`` [N, 3] and ``template`` [M, 3] in the same units (metres or model units); the template is in the
    category frame. Result (R [3, 3], t [3]) maps the template into the observation: x ≈ R @ y + t (column vectors),
    i.e. the same pose convention as the network. All 60 initialisations run together (batched Kabsch via SVD);
    nearest neighbours by scipy ``cKDTree``.
    ``bidirectional`` (complete shapes) adds template→observation correspondences; partial observations use only
    observation→template, as a partial view covers part of the template.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from equipose import icosahedral
from equipose.errors import InvalidPointsError

__all__ = ["kabsch", "icp_multi", "icp60", "icp60_outputs"]


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple:
    """Batched least-squares rigid fit dst ≈ R src + t. src, dst [B, K, 3] → R [B, 3, 3], t [B, 3]."""
    ms, md = src.mean(1, keepdims=True), dst.mean(1, keepdims=True)          # [B, 1, 3]
    H = np.einsum("bki,bkj->bij", src - ms, dst - md)                         # [B, 3, 3]
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("bij,bjk->bik", U, Vt).transpose(0, 2, 1)))
    D = np.tile(np.eye(3), (len(H), 1, 1))
    D[:, 2, 2] = d
    R = np.einsum("bji,bjk,blk->bil", Vt, D, U)                               # V D Uᵀ
    t = md[:, 0] - np.einsum("bij,bj->bi", R, ms[:, 0])
    return R, t


def icp_multi(observed: np.ndarray, template: np.ndarray, R0: np.ndarray, t0: np.ndarray, iters: int = 30,
              bidirectional: bool = False, tree: cKDTree | None = None) -> tuple:
    """ICP from several initial poses at once. R0 [J, 3, 3], t0 [J, 3] → (R [J,3,3], t [J,3], residual [J]).

    Residual: mean squared nearest-neighbour distance (observation→template, plus the reverse if bidirectional).
    """
    x = np.asarray(observed, np.float64)                                       # [N, 3]
    y = np.asarray(template, np.float64)                                       # [M, 3]
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 3 or y.ndim != 2 or y.shape[1] != 3 or len(y) < 3:
        raise InvalidPointsError(f"ICP needs [N≥3, 3] point arrays, got {x.shape} and {y.shape}")
    tree = tree or cKDTree(y)
    obs_tree = cKDTree(x) if bidirectional else None
    R, t = np.array(R0, np.float64), np.array(t0, np.float64)
    J, N, M = len(R), len(x), len(y)
    for it in range(iters + 1):
        local = np.einsum("jni,jik->jnk", (x[None] - t[:, None]), R)           # [J, N, 3] = Rᵀ(x − t)
        d1, i1 = tree.query(local.reshape(-1, 3))
        res = (d1.reshape(J, N) ** 2).mean(1)                                  # [J]
        src, dst = y[i1.reshape(J, N)], np.broadcast_to(x, (J, N, 3))         # template pts ↔ observed pts
        if bidirectional:
            posed = np.einsum("mk,jik->jmi", y, R) + t[:, None]               # [J, M, 3] = R y + t
            d2, i2 = obs_tree.query(posed.reshape(-1, 3))
            res = res + (d2.reshape(J, M) ** 2).mean(1)
            src = np.concatenate([src, np.broadcast_to(y, (J, M, 3))], 1)
            dst = np.concatenate([dst, x[i2.reshape(J, M)]], 1)
        if it == iters:
            break
        R, t = kabsch(src, np.ascontiguousarray(dst))
    return R, t, res


def icp60(observed: np.ndarray, template: np.ndarray, iters: int = 30, bidirectional: bool = False) -> tuple:
    """Best of 60 ICP runs started at the icosahedral rotations (translation: centroid alignment).

    Returns (R [3, 3], t [3], residual float).
    """
    x, y = np.asarray(observed, np.float64), np.asarray(template, np.float64)
    A = icosahedral.ANCHORS.astype(np.float64)                                 # [60, 3, 3]
    t0 = x.mean(0)[None] - np.einsum("jik,k->ji", A, y.mean(0))               # [60, 3]
    R, t, res = icp_multi(x, y, A, t0, iters=iters, bidirectional=bidirectional)
    j = int(np.argmin(res))
    return R[j], t[j], float(res[j])


def icp60_outputs(model_points: np.ndarray, template: np.ndarray, iters: int = 30, bidirectional: bool = False) -> dict:
    """ICP-60 in the network's output contract, so the SDK's selection and calibration apply unchanged.

    Convention: ``model_points`` [B, N, 3] model units; ``template`` [M, 3] in the frame the hypotheses refer to (the
    network's learned frame when it is the model's own canonical shape). Returns numpy ``hypothesis_rotations``
    [B, 60, 3, 3], ``hypothesis_translations`` [B, 60, 3], ``hypothesis_scores`` [B, 60] (final residual; lower is
    better, as the chamfer scores) and ``canonical_shape`` [B, M, 3] (the template).
    """
    x = np.asarray(model_points, np.float64)
    if x.ndim != 3 or x.shape[-1] != 3:
        raise InvalidPointsError(f"ICP-60 outputs need model points [B, N, 3], got {x.shape}")
    y = np.asarray(template, np.float64)
    A = icosahedral.ANCHORS.astype(np.float64)                                 # [60, 3, 3]
    tree = cKDTree(y)
    Rs, ts, rs = [], [], []
    for xb in x:
        t0 = xb.mean(0)[None] - np.einsum("jik,k->ji", A, y.mean(0))           # [60, 3]
        R, t, res = icp_multi(xb, y, A, t0, iters=iters, bidirectional=bidirectional, tree=tree)
        Rs.append(R); ts.append(t); rs.append(res)
    return {"hypothesis_rotations": np.stack(Rs).astype(np.float32), "hypothesis_translations": np.stack(ts).astype(np.float32),
            "hypothesis_scores": np.stack(rs).astype(np.float32),
            "canonical_shape": np.broadcast_to(y.astype(np.float32), (len(x),) + y.shape).copy()}
