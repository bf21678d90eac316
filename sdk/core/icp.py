"""Batched rigid ICP: many starts (hypotheses × copies × templates) against one observation, in one compiled loop.

Convention:
    Poses map a template into the observation, ``x ≈ R @ y + t`` (column vectors), both in one unit (the SDK uses
    model units). Residual of a pose: mean squared nearest-neighbour distance observation → template, plus
    template → observation when ``bidirectional`` (complete inputs; a partial view covers only part of a template).
    Every start of one call shares the observation; starts may use different templates of equal size (``which``).
    Nearest neighbours: exact (float32 distances), by ``equipose.core.nearest`` — brute force for small sets, k-d
    trees warm-started from each point's previous partner for large ones.
    Rotation updates: Horn's closed form (the unit quaternion maximising Σ dᵀ R s, the top eigenvector of a
    symmetric 4 × 4 matrix), the same least-squares rotation as Kabsch's SVD and always proper.
    ``icp_point_to_plane``: the point-to-plane variant against a template with normals (a Gauss–Newton step of the
    linearised distances along the normals per iteration), which does not creep along flat parts of a surface.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError
from equipose.core.eigen import top_eigenvector
from equipose.core.nearest import build_index, make_scratch, nearest_brute, nearest_tree
from equipose.core.parallel import run_parts, split_ranges
from equipose.core.parallel import workers as workers_in_scope

__all__ = ["kabsch", "icp_multi", "icp_point_to_plane"]


def kabsch(src: np.ndarray, dst: np.ndarray) -> tuple:
    """Batched least-squares rigid fit ``dst ≈ R src + t``.

    Convention: ``src``, ``dst`` [B, K, 3] paired points → R [B, 3, 3] (proper rotations), t [B, 3].
    """
    ms, md = src.mean(1), dst.mean(1)                                           # [B, 3]
    H = np.matmul(np.transpose(src, (0, 2, 1)), dst - md[:, None])             # [B, 3, 3] Σ src (dst − d̄)ᵀ
    U, _, Vt = np.linalg.svd(H)
    R = np.matmul(U, Vt).transpose(0, 2, 1)                                     # [B, 3, 3] V Uᵀ
    flip = np.linalg.det(R) < 0                                                 # reflections: V diag(1, 1, −1) Uᵀ
    if flip.any():
        Vt[flip, 2] *= -1.0
        R[flip] = np.matmul(U[flip], Vt[flip]).transpose(0, 2, 1)
    return R, md - np.einsum("bij,bj->bi", R, ms)


@njit(cache=True)
def _fit_rotation(H, R):
    """R [3, 3] (written in place) = the rotation maximising tr(R H) for the cross-covariance
    H = Σ (s − s̄)(d − d̄)ᵀ, i.e. the least-squares rotation of d ≈ R s (Horn's quaternion)."""
    Sxx, Sxy, Sxz = H[0, 0], H[0, 1], H[0, 2]
    Syx, Syy, Syz = H[1, 0], H[1, 1], H[1, 2]
    Szx, Szy, Szz = H[2, 0], H[2, 1], H[2, 2]
    N = np.empty((4, 4))
    N[0, 0], N[0, 1], N[0, 2], N[0, 3] = Sxx + Syy + Szz, Syz - Szy, Szx - Sxz, Sxy - Syx
    N[1, 1], N[1, 2], N[1, 3] = Sxx - Syy - Szz, Sxy + Syx, Szx + Sxz
    N[2, 2], N[2, 3] = -Sxx + Syy - Szz, Syz + Szy
    N[3, 3] = -Sxx - Syy + Szz
    for i in range(4):
        for j in range(i):
            N[i, j] = N[j, i]
    w, x, y, z = top_eigenvector(N)
    R[0, 0], R[0, 1], R[0, 2] = w * w + x * x - y * y - z * z, 2 * (x * y - w * z), 2 * (x * z + w * y)
    R[1, 0], R[1, 1], R[1, 2] = 2 * (x * y + w * z), w * w - x * x + y * y - z * z, 2 * (y * z - w * x)
    R[2, 0], R[2, 1], R[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), w * w - x * x - y * y + z * z


@njit(cache=True)
def _hold_axis(R, axis, up):
    """Turn R [3, 3] in place by the smallest rotation that takes its column ``axis`` onto the unit ``up`` [3]
    (for the opposite direction: the half turn about an axis perpendicular to the column): what
    ``equipose.core.geometry.rotation_between`` computes, inside the compiled loop."""
    a = R[:, axis].copy()
    a /= np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
    v = np.array([a[1] * up[2] - a[2] * up[1], a[2] * up[0] - a[0] * up[2], a[0] * up[1] - a[1] * up[0]])
    c = a[0] * up[0] + a[1] * up[1] + a[2] * up[2]
    if c < -1.0 + 1e-9:
        k = np.argmin(np.abs(a))
        e = np.zeros(3)
        e[k] = 1.0
        p = np.array([a[1] * e[2] - a[2] * e[1], a[2] * e[0] - a[0] * e[2], a[0] * e[1] - a[1] * e[0]])
        p /= np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        T = 2.0 * np.outer(p, p) - np.eye(3)
    else:
        V = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
        T = np.eye(3) + V + (V @ V) / max(1.0 + c, 1e-12)
    R[:, :] = T @ R


@njit(cache=True, inline="always")
def _add_pair(S, ss, ds, Y, m, x, n):
    """Accumulate the pair template point Y[m] ↔ observed point x[n]: S += s dᵀ, ss += s, ds += d."""
    for a in range(3):
        ss[a] += Y[m, a]
        ds[a] += x[n, a]
        for b in range(3):
            S[a, b] += Y[m, a] * x[n, b]


@njit(cache=True, nogil=True)
def _icp_loop(x, Y, which, R, t, iters, bidirectional, hold_axis, up, tol, res):
    """The ICP of every start, in place on R [J, 3, 3], t [J, 3], res [J] (see ``icp_multi``)."""
    N, M = x.shape[0], Y.shape[1]
    K = N + (M if bidirectional else 0)
    stack, bound, dist, bits = make_scratch(max(N, M))
    pairs, last = np.empty(K, np.int64), np.empty(K, np.int64)
    _, soa, centre, tpoints, ids, nodes, split = build_index(Y)                # templates, unpacked once
    xs = x.reshape(1, N, 3) if bidirectional else np.ascontiguousarray(x[:1]).reshape(1, 1, 3)   # one-point stand-in
    _, xsoa, xcentre, xtpoints, xids, xnodes, xsplit = build_index(xs)          # when only observed → template
    tree, xtree = tpoints.shape[1] > 0, xtpoints.shape[1] > 0
    H, q, Rold = np.empty((3, 3)), np.empty(3), np.empty((3, 3))
    for j in range(R.shape[0]):
        w = which[j]
        Yw = Y[w]
        pairs[:] = -1
        settled = False
        if hold_axis >= 0:
            _hold_axis(R[j], hold_axis, up)
        for it in range(iters + 1):
            Rj, tj = R[j], t[j]
            S = np.zeros((3, 3))                                               # Σ s dᵀ over the pairs
            ss, ds = np.zeros(3), np.zeros(3)                                   # Σ s, Σ d
            r1 = 0.0
            for n in range(N):                                                  # observed → template
                px, py, pz = x[n, 0] - tj[0], x[n, 1] - tj[1], x[n, 2] - tj[2]
                q[0] = Rj[0, 0] * px + Rj[1, 0] * py + Rj[2, 0] * pz            # Rᵀ(x − t)
                q[1] = Rj[0, 1] * px + Rj[1, 1] * py + Rj[2, 1] * pz
                q[2] = Rj[0, 2] * px + Rj[1, 2] * py + Rj[2, 2] * pz
                if tree:
                    m = nearest_tree(tpoints, ids, nodes, split, w, q, pairs[n], stack, bound)
                else:
                    m = nearest_brute(soa, centre, w, q, dist, bits)
                d2 = (Yw[m, 0] - q[0]) ** 2 + (Yw[m, 1] - q[1]) ** 2 + (Yw[m, 2] - q[2]) ** 2
                last[n] = m
                r1 += d2
                _add_pair(S, ss, ds, Yw, m, x, n)
            r = r1 / N
            if bidirectional:                                                   # template → observed
                r2 = 0.0
                for m in range(M):
                    y0, y1, y2 = Yw[m, 0], Yw[m, 1], Yw[m, 2]
                    q[0] = Rj[0, 0] * y0 + Rj[0, 1] * y1 + Rj[0, 2] * y2 + tj[0]    # R y + t
                    q[1] = Rj[1, 0] * y0 + Rj[1, 1] * y1 + Rj[1, 2] * y2 + tj[1]
                    q[2] = Rj[2, 0] * y0 + Rj[2, 1] * y1 + Rj[2, 2] * y2 + tj[2]
                    if xtree:
                        n = nearest_tree(xtpoints, xids, xnodes, xsplit, 0, q, pairs[N + m], stack, bound)
                    else:
                        n = nearest_brute(xsoa, xcentre, 0, q, dist, bits)
                    d2 = (x[n, 0] - q[0]) ** 2 + (x[n, 1] - q[1]) ** 2 + (x[n, 2] - q[2]) ** 2
                    last[N + m] = n
                    r2 += d2
                    _add_pair(S, ss, ds, Yw, m, x, n)
                r += r2 / M
            res[j] = r
            if it == iters or settled:
                break
            same = True                                                         # same pairs as the step that led
            for k in range(K):                                                  # here: its fit is this pose again
                if last[k] != pairs[k]:
                    same = False
                pairs[k] = last[k]
            if same:
                break
            for a in range(3):
                for b in range(3):
                    H[a, b] = S[a, b] - ss[a] * ds[b] / K                       # Σ (s − s̄)(d − d̄)ᵀ
            Rold[:, :] = Rj
            t0, t1, t2 = tj[0], tj[1], tj[2]
            _fit_rotation(H, Rj)
            if hold_axis >= 0:
                _hold_axis(Rj, hold_axis, up)
            for a in range(3):                                                  # best translation for that R
                tj[a] = (ds[a] - Rj[a, 0] * ss[0] - Rj[a, 1] * ss[1] - Rj[a, 2] * ss[2]) / K
            if tol > 0.0:                                                       # a step below tol: one more pass
                c = 0.0                                                         # for the residual, then stop
                for a in range(3):
                    for b in range(3):
                        c += Rold[a, b] * Rj[a, b]                              # tr(Rold^T R) = 1 + 2 cos(angle)
                dt2 = (tj[0] - t0) ** 2 + (tj[1] - t1) ** 2 + (tj[2] - t2) ** 2
                settled = c > 3.0 - tol * tol and dt2 < tol * tol


def icp_multi(observed: np.ndarray, template: np.ndarray, R0: np.ndarray, t0: np.ndarray, iters: int = 30,
              bidirectional: bool = False, which=None, hold=None, workers: int | None = None,
              tol: float = 0.0) -> tuple:
    """ICP from several starts at once.

    Convention: ``observed`` [N ≥ 3, 3]; ``template`` [M ≥ 3, 3], or [T, M, 3] with ``which`` [J] the template of
    each start; ``R0`` [J, 3, 3], ``t0`` [J, 3]. Returns (R [J, 3, 3], t [J, 3], residual [J]) after ``iters``
    updates (the residual is that of the returned pose).

    ``hold``: optional (axis, direction [3]): every rotation keeps its column ``axis`` on ``direction`` — the starts
    and every update are turned onto it by the smallest rotation, and the translation is re-fitted for the held
    rotation (e.g. the up prior's "keep +z on up"). A start whose nearest-neighbour pairs repeat those of the step
    that moved it is at a fixed point (the fit of the same pairs is the same pose) and stops early with exactly the
    result the remaining iterations would give. ``tol`` > 0 also stops a start after the first update that turns it
    by less than ``tol`` radians and moves it by less than ``tol`` template units (its residual is then that of the
    updated pose); the default 0 runs every iteration short of a fixed point.

    Each update is the least-squares rigid fit of all pairs (observed → template, and template → observed when
    bidirectional), accumulated without storing them: H = Σ s dᵀ − K s̄ d̄ᵀ over the K pairs of a start.

    ``workers``: the starts run in up to that many contiguous parts side by side (``equipose.core.parallel``; None:
    the caller's ``kernel_workers`` scope, 1 outside one); every start's result is the same either way.
    """
    x = np.ascontiguousarray(observed, np.float64)                             # [N, 3]
    Y = np.asarray(template, np.float64)
    Y = np.ascontiguousarray(Y[None] if Y.ndim == 2 else Y)                     # [T, M, 3]
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 3 or Y.ndim != 3 or Y.shape[2] != 3 or Y.shape[1] < 3:
        raise InvalidPointsError(f"ICP needs [N≥3, 3] point arrays, got {x.shape} and {np.shape(template)}")
    R, t = np.array(R0, np.float64, order="C"), np.array(t0, np.float64, order="C")
    J = len(R)
    if R.shape != (J, 3, 3) or t.shape != (J, 3):
        raise InvalidPointsError(f"ICP starts must be R0 [J, 3, 3] and t0 [J, 3], got {R.shape}, {t.shape}")
    which = np.zeros(J, np.int64) if which is None else np.ascontiguousarray(which, np.int64)   # [J] each start's
    if which.shape != (J,) or (J and (which.min() < 0 or which.max() >= len(Y))):
        raise InvalidPointsError(f"ICP which must index the {len(Y)} templates for each of the {J} starts")
    axis, up = -1, np.zeros(3)
    if hold is not None:
        axis, up = int(hold[0]), np.asarray(hold[1], np.float64)
        up = np.ascontiguousarray(up / np.linalg.norm(up))
    res = np.zeros(J)
    parts = split_ranges(J, workers_in_scope() if workers is None else workers) if J else []
    run_parts(_icp_loop, [(x, Y, which[a:b], R[a:b], t[a:b], int(iters), bool(bidirectional), axis, up,
                           float(tol), res[a:b])
                          for a, b in parts])                                   # in place on views of R, t, res
    return R, t, res


@njit(cache=True, inline="always")
def _rotation_from_vector(w0, w1, w2, M) -> None:
    """M [3, 3] (in place) = exp([w]×), the rotation by |w| radians about w (Rodrigues)."""
    th = np.sqrt(w0 * w0 + w1 * w1 + w2 * w2)
    a = np.sin(th) / th if th > 1e-12 else 1.0
    b = (1.0 - np.cos(th)) / (th * th) if th > 1e-12 else 0.5
    M[0, 0], M[0, 1], M[0, 2] = 1.0 - b * (w1 * w1 + w2 * w2), -a * w2 + b * w0 * w1, a * w1 + b * w0 * w2
    M[1, 0], M[1, 1], M[1, 2] = a * w2 + b * w0 * w1, 1.0 - b * (w0 * w0 + w2 * w2), -a * w0 + b * w1 * w2
    M[2, 0], M[2, 1], M[2, 2] = -a * w1 + b * w0 * w2, a * w0 + b * w1 * w2, 1.0 - b * (w0 * w0 + w1 * w1)


@njit(cache=True, nogil=True)
def _icp_plane_loop(x, Y, normals, R, t, iters, tol, res, max_dist):
    """Point-to-plane ICP of every start, in place on R [J, 3, 3], t [J, 3], res [J] (see ``icp_point_to_plane``);
    ``max_dist`` > 0: pairs farther apart leave the step, and each adds ``max_dist``² to the residual."""
    trim2 = max_dist * max_dist if max_dist > 0 else np.inf
    N = x.shape[0]
    stack, bound, dist, bits = make_scratch(Y.shape[1])
    pairs = np.empty(N, np.int64)
    _, soa, centre, tpoints, ids, nodes, split = build_index(Y)
    tree = tpoints.shape[1] > 0
    Y0, q, M = Y[0], np.empty(3), np.empty((3, 3))
    A, b = np.empty((6, 6)), np.empty(6)
    J6 = np.empty(6)
    for j in range(R.shape[0]):
        pairs[:] = -1
        Rj, tj = R[j], t[j]
        for it in range(iters + 1):
            A[:] = 0.0
            b[:] = 0.0
            r1 = 0.0
            kept = 0
            for n in range(N):
                px, py, pz = x[n, 0] - tj[0], x[n, 1] - tj[1], x[n, 2] - tj[2]
                q[0] = Rj[0, 0] * px + Rj[1, 0] * py + Rj[2, 0] * pz            # Rᵀ(x − t): template frame
                q[1] = Rj[0, 1] * px + Rj[1, 1] * py + Rj[2, 1] * pz
                q[2] = Rj[0, 2] * px + Rj[1, 2] * py + Rj[2, 2] * pz
                if tree:
                    m = nearest_tree(tpoints, ids, nodes, split, 0, q, pairs[n], stack, bound)
                else:
                    m = nearest_brute(soa, centre, 0, q, dist, bits)
                pairs[n] = m
                d0, d1, d2 = q[0] - Y0[m, 0], q[1] - Y0[m, 1], q[2] - Y0[m, 2]
                dd = d0 * d0 + d1 * d1 + d2 * d2
                if dd > trim2:                                                  # trimmed: not this surface's
                    r1 += trim2
                    continue
                r1 += dd
                kept += 1
                n0, n1, n2 = normals[m, 0], normals[m, 1], normals[m, 2]
                e = d0 * n0 + d1 * n1 + d2 * n2                                 # distance along the normal
                J6[0], J6[1], J6[2] = q[1] * n2 - q[2] * n1, q[2] * n0 - q[0] * n2, q[0] * n1 - q[1] * n0
                J6[3], J6[4], J6[5] = n0, n1, n2                                # ∂e / ∂(ω, v) of q → q + ω × q + v
                for a in range(6):
                    b[a] += J6[a] * e
                    for c in range(a, 6):
                        A[a, c] += J6[a] * J6[c]
            res[j] = r1 / N
            if it == iters or kept < 6:
                break
            damp = 1e-9 * (A[0, 0] + A[1, 1] + A[2, 2] + A[3, 3] + A[4, 4] + A[5, 5]) + 1e-15
            for a in range(6):
                A[a, a] += damp
                for c in range(a):
                    A[a, c] = A[c, a]
            step = np.linalg.solve(A, -b)                                       # (ω, v) in the template frame
            if np.sqrt(step[0] ** 2 + step[1] ** 2 + step[2] ** 2) < tol and \
                    np.sqrt(step[3] ** 2 + step[4] ** 2 + step[5] ** 2) < tol:
                break                                                           # converged: res is this pose's
            _rotation_from_vector(step[0], step[1], step[2], M)
            # q' = M q + v for q = Rᵀ(x − t): R' = R Mᵀ, t' = t − R' v
            Rn = Rj @ M.T
            for a in range(3):
                tj[a] -= Rn[a, 0] * step[3] + Rn[a, 1] * step[4] + Rn[a, 2] * step[5]
            Rj[:, :] = Rn


def icp_point_to_plane(observed: np.ndarray, template: np.ndarray, normals: np.ndarray, R0: np.ndarray,
                       t0: np.ndarray, iters: int = 20, tol: float = 1e-7, workers: int | None = None,
                       max_dist: float = 0.0) -> tuple:
    """Point-to-plane ICP from several starts at once (observation → template).

    Convention: ``observed`` [N ≥ 6, 3]; ``template`` [M ≥ 3, 3] with unit ``normals`` [M, 3] (any sign, e.g.
    ``equipose.core.normals.point_normals``); ``R0`` [J, 3, 3], ``t0`` [J, 3] with x ≈ R y + t. Each iteration pairs
    every observed point with its nearest template point and takes the Gauss–Newton step (a rotation vector and a
    translation in the template frame) that minimises the squared distances along the template normals, linearised.
    A start stops when a step is below ``tol`` (radians, and template units) or after ``iters`` steps. Returns
    (R [J, 3, 3], t [J, 3], residual [J]) with the residual of the returned pose as ``icp_multi`` reports it (the
    mean squared point-to-point distance observation → template), so the two rank alike. ``workers``: as in
    ``icp_multi``. ``max_dist`` > 0 (template units) trims: an observed point farther than it from its nearest
    template point takes no part in the step and adds ``max_dist``² to the residual (a truncated mean: the points of
    a neighbour in the crop cannot pull the pose). A start with fewer than 6 pairs left keeps its pose.
    """
    x = np.ascontiguousarray(observed, np.float64)                             # [N, 3]
    Y = np.ascontiguousarray(np.asarray(template, np.float64)[None])           # [1, M, 3]
    nrm = np.ascontiguousarray(normals, np.float64)                            # [M, 3]
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 6 or Y.ndim != 3 or Y.shape[2] != 3 or Y.shape[1] < 3 or \
            nrm.shape != Y.shape[1:]:
        raise InvalidPointsError(f"point-to-plane ICP needs observed [N≥6, 3], template [M≥3, 3] and normals [M, 3], "
                                 f"got {x.shape}, {np.shape(template)}, {nrm.shape}")
    R, t = np.array(R0, np.float64, order="C"), np.array(t0, np.float64, order="C")
    J = len(R)
    if R.shape != (J, 3, 3) or t.shape != (J, 3):
        raise InvalidPointsError(f"ICP starts must be R0 [J, 3, 3] and t0 [J, 3], got {R.shape}, {t.shape}")
    res = np.zeros(J)
    parts = split_ranges(J, workers_in_scope() if workers is None else workers) if J else []
    if not (np.isfinite(max_dist) and max_dist >= 0):
        raise InvalidPointsError(f"point-to-plane ICP max_dist must be ≥ 0 (0: no trimming), got {max_dist!r}")
    run_parts(_icp_plane_loop, [(x, Y, nrm, R[a:b], t[a:b], int(iters), float(tol), res[a:b], float(max_dist))
                                for a, b in parts])
    return R, t, res
