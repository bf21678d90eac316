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
    ms, md = src.mean(1, keepdims=True), dst.mean(1, keepdims=True)           # [B, 1, 3]
    H = np.einsum("bki,bkj->bij", src - ms, dst - md)                          # [B, 3, 3]
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(U @ Vt))                                          # [B] det(V Uᵀ) = det(U Vᵀ)
    Vt[:, 2] *= d[:, None]                                                      # V D, D = diag(1, 1, d)
    R = np.transpose(Vt, (0, 2, 1)) @ np.transpose(U, (0, 2, 1))               # [B, 3, 3] = V D Uᵀ
    t = md[:, 0] - np.einsum("bij,bj->bi", R, ms[:, 0])                        # [B, 3]
    return R, t


def _to_local(x: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[L, N, 3] = Rᵀ(x − t) for each start: one product x · [R_1 … R_L] ([N, 3] · [3, 3L])."""
    L = len(R)
    flat = x @ np.transpose(R, (1, 0, 2)).reshape(3, 3 * L)                    # [N, 3L]
    shift = np.einsum("li,lik->lk", t, R)                                       # [L, 3] = Rᵀ t
    return flat.reshape(len(x), L, 3).transpose(1, 0, 2) - shift[:, None]      # [L, N, 3]


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
    index = {int(k): tree if (tree is not None and len(Y) == 1) else NearestNeighbours(Y[k]) for k in np.unique(which)}
    obs_index = (observed_tree or NearestNeighbours(x)) if bidirectional else None
    flat = Y.reshape(-1, 3)                                                    # [T·M, 3]
    if constrain is not None:
        R = constrain(R)
    res = np.empty(J)
    last = np.full((J, N + (M if bidirectional else 0)), -1)                   # [J, ·] previous correspondences
    live = np.arange(J)                                                        # starts still moving
    for it in range(iters + 1):
        Ra, ta, wa = R[live], t[live], which[live]                             # [L, 3, 3], [L, 3], [L]
        L = len(live)
        local = _to_local(x, Ra, ta)                                           # [L, N, 3] = Rᵀ(x − t)
        d1, i1 = np.empty((L, N)), np.empty((L, N), int)
        for k in np.unique(wa):
            js = np.nonzero(wa == k)[0]
            d, i = index[int(k)].query(local[js].reshape(-1, 3))
            d1[js], i1[js] = d.reshape(len(js), N), i.reshape(len(js), N)
        res[live] = np.einsum("ln,ln->l", d1, d1) / N                         # [L]
        src, dst = flat[wa[:, None] * M + i1], np.broadcast_to(x, (L, N, 3))   # template ↔ observed points
        pairs = i1
        if bidirectional:
            Yl = np.broadcast_to(Y[0], (L, M, 3)) if len(Y) == 1 else Y[wa]   # [L, M, 3] each start's template
            posed = Yl @ np.transpose(Ra, (0, 2, 1)) + ta[:, None]            # [L, M, 3] = R y + t
            d2, i2 = obs_index.query(posed.reshape(-1, 3))
            d2, i2 = d2.reshape(L, M), i2.reshape(L, M)
            res[live] += np.einsum("lm,lm->l", d2, d2) / M
            src = np.concatenate([src, Yl], 1)
            dst = np.concatenate([dst, x[i2]], 1)
            pairs = np.concatenate([i1, i2], 1)
        if it == iters:
            break
        # same pairs as the step that led here: that step's fit is this pose again, so the start has converged
        moving = ~(pairs == last[live]).all(1)                                 # [L]
        last[live] = pairs
        if not moving.all():
            live, src, dst = live[moving], src[moving], dst[moving]
            if not len(live):
                break
        Rn, tn = kabsch(src, dst)
        if constrain is not None:
            Rn = constrain(Rn)
            tn = dst.mean(1) - np.einsum("jik,jk->ji", Rn, src.mean(1))        # best translation for that R
        R[live], t[live] = Rn, tn
    return R, t, res
