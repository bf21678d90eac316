"""Batched rigid ICP: many starts (hypotheses × copies × templates) against one observation in one loop.

Convention:
    Poses map a template into the observation, ``x ≈ R @ y + t`` (column vectors), both in one unit (the SDK uses
    model units). Residual of a pose: mean squared nearest-neighbour distance observation → template, plus
    template → observation when ``bidirectional`` (complete inputs; a partial view covers only part of a template).
    Every start of one call shares the observation; starts may use different templates of equal size (``which``).
    Nearest neighbours: ``equipose.core.neighbours`` (one structure per template and one for the observation, built
    once per call or passed in), queried for all live starts of a template in one batch.
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import InvalidPointsError
from equipose.core.neighbours import NearestNeighbours

__all__ = ["kabsch", "icp_multi"]


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple:
    """Batched least-squares rigid fit ``dst ≈ R src + t``.

    Convention: ``src``, ``dst`` [B, K, 3] paired points → R [B, 3, 3] (proper rotations), t [B, 3].
    """
    ms, md = src.mean(1), dst.mean(1)                                           # [B, 3]
    H = np.matmul(np.transpose(src, (0, 2, 1)), dst - md[:, None])             # [B, 3, 3] Σ src (dst − d̄)ᵀ
    return _rotation_from_covariance(H, ms, md)


def _rotation_from_covariance(H: np.ndarray, ms: np.ndarray, md: np.ndarray) -> tuple:
    """Kabsch's rotation of the cross-covariance H [B, 3, 3] (= Σ (s − s̄)(d − d̄)ᵀ) and the translation that maps the
    source mean ``ms`` [B, 3] onto the destination mean ``md`` [B, 3]."""
    U, _, Vt = np.linalg.svd(H)
    R = np.matmul(U, Vt).transpose(0, 2, 1)                                     # [B, 3, 3] V Uᵀ
    flip = np.linalg.det(R) < 0                                                 # reflections: V diag(1, 1, −1) Uᵀ
    if flip.any():
        Vt[flip, 2] *= -1.0
        R[flip] = np.matmul(U[flip], Vt[flip]).transpose(0, 2, 1)
    t = md - np.einsum("bij,bj->bi", R, ms)                                     # [B, 3]
    return R, t


def _to_local(x: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[L, N, 3] = Rᵀ(x − t) for each start: one product x · [R_1 … R_L] ([N, 3] · [3, 3L])."""
    L = len(R)
    flat = x @ np.transpose(R, (1, 0, 2)).reshape(3, 3 * L)                    # [N, 3L]
    shift = np.einsum("li,lik->lk", t, R)                                       # [L, 3] = Rᵀ t
    return flat.reshape(len(x), L, 3).transpose(1, 0, 2) - shift[:, None]      # [L, N, 3]


def _indices(index, queries: np.ndarray) -> np.ndarray:
    """Nearest-neighbour indices from a ``NearestNeighbours`` or any structure with ``query`` (e.g. cKDTree)."""
    return index.nearest_indices(queries) if hasattr(index, "nearest_indices") else index.query(queries)[1]


def icp_multi(observed: np.ndarray, template: np.ndarray, R0: np.ndarray, t0: np.ndarray, iters: int = 30,
              bidirectional: bool = False, tree=None, constrain=None, which=None, observed_tree=None) -> tuple:
    """ICP from several starts at once.

    Convention: ``observed`` [N ≥ 3, 3]; ``template`` [M ≥ 3, 3], or [T, M, 3] with ``which`` [J] the template of
    each start; ``R0`` [J, 3, 3], ``t0`` [J, 3]. Returns (R [J, 3, 3], t [J, 3], residual [J]) after ``iters``
    updates (the residual is that of the returned pose).

    ``tree``: a prebuilt nearest-neighbour structure of a single template (``NearestNeighbours`` or anything with
    its ``query``), ``observed_tree`` the same for the observation. ``constrain``: optional map of rotations
    [J, 3, 3] → [J, 3, 3] applied to the starts and after every Kabsch step (the translation is then re-fitted for
    the constrained rotation), e.g. the up prior's "keep +z on up". A start whose nearest-neighbour pairs repeat
    those of the step that moved it is at a fixed point (the fit of the same pairs is the same pose) and leaves the
    loop early with exactly the result the remaining iterations would give.

    Each update is Kabsch's fit of all pairs (observed → template, and template → observed when bidirectional),
    accumulated without stacking them: H = Σ s dᵀ − K s̄ d̄ᵀ over the K pairs of a start.
    """
    x = np.asarray(observed, np.float64)                                       # [N, 3]
    Y = np.asarray(template, np.float64)
    Y = Y[None] if Y.ndim == 2 else Y                                          # [T, M, 3]
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 3 or Y.ndim != 3 or Y.shape[2] != 3 or Y.shape[1] < 3:
        raise InvalidPointsError(f"ICP needs [N≥3, 3] point arrays, got {x.shape} and {np.shape(template)}")
    R, t = np.array(R0, np.float64), np.array(t0, np.float64)
    J, N, M = len(R), len(x), Y.shape[1]
    if R.shape != (J, 3, 3) or t.shape != (J, 3):
        raise InvalidPointsError(f"ICP starts must be R0 [J, 3, 3] and t0 [J, 3], got {R.shape}, {t.shape}")
    which = np.zeros(J, int) if which is None else np.asarray(which, int)      # [J] template of each start
    groups = np.unique(which)
    index = {int(k): tree if (tree is not None and len(Y) == 1) else NearestNeighbours(Y[k]) for k in groups}
    obs_index = (observed_tree or NearestNeighbours(x)) if bidirectional else None
    x_sum = x.sum(0)                                                           # [3]
    K = N + (M if bidirectional else 0)                                        # pairs per start
    if constrain is not None:
        R = constrain(R)
    res = np.empty(J)
    last = np.full((J, K), -1)                                                 # [J, K] previous correspondences
    live = np.arange(J)                                                        # starts still moving
    for it in range(iters + 1):
        L = len(live)
        Ra, ta, wa = R[live], t[live], which[live]                             # [L, 3, 3], [L, 3], [L]
        local = _to_local(x, Ra, ta)                                           # [L, N, 3] = Rᵀ(x − t)
        if len(groups) == 1:
            i1 = _indices(index[int(groups[0])], local.reshape(-1, 3)).reshape(L, N)
        else:
            i1 = np.empty((L, N), int)
            for k in np.unique(wa):
                js = np.nonzero(wa == k)[0]
                i1[js] = _indices(index[int(k)], local[js].reshape(-1, 3)).reshape(len(js), N)
        src = Y[wa[:, None], i1]                                               # [L, N, 3] template ↔ observed
        diff = local - src
        res[live] = np.einsum("lni,lni->l", diff, diff) / N                   # [L]
        pairs = i1
        if bidirectional:
            Yl = Y[wa]                                                         # [L, M, 3] each start's template
            posed = np.matmul(Yl, np.transpose(Ra, (0, 2, 1))) + ta[:, None]   # [L, M, 3] = R y + t
            i2 = _indices(obs_index, posed.reshape(-1, 3)).reshape(L, M)
            back = x[i2]                                                       # [L, M, 3]
            d2 = posed - back
            res[live] += np.einsum("lmi,lmi->l", d2, d2) / M
            pairs = np.concatenate([i1, i2], 1)
        if it == iters:
            break
        # same pairs as the step that led here: that step's fit is this pose again, so the start has converged
        moving = (pairs != last[live]).any(1)                                  # [L]
        last[live] = pairs
        if not moving.all():
            live, src = live[moving], src[moving]
            if bidirectional:
                Yl, back = Yl[moving], back[moving]
            if not len(live):
                break
        S = np.matmul(np.transpose(src, (0, 2, 1)), x)                         # [L, 3, 3] Σ s dᵀ
        s_sum, d_sum = src.sum(1), np.broadcast_to(x_sum, (len(live), 3))      # [L, 3]
        if bidirectional:
            S = S + np.matmul(np.transpose(Yl, (0, 2, 1)), back)
            s_sum, d_sum = s_sum + Yl.sum(1), d_sum + back.sum(1)
        ms, md = s_sum / K, d_sum / K                                          # [L, 3] pair means
        H = S - K * ms[:, :, None] * md[:, None, :]                            # [L, 3, 3]
        Rn, tn = _rotation_from_covariance(H, ms, md)
        if constrain is not None:
            Rn = constrain(Rn)
            tn = md - np.einsum("jik,jk->ji", Rn, ms)                          # best translation for that R
        R[live], t[live] = Rn, tn
    return R, t, res
