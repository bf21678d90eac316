"""A denser ICP template: the predicted canonical shape plus midpoints between neighbouring points.

The network predicts its canonical shape as a few hundred points (256 for the edge presets) and the observation has
as many. ICP pairs each observed point with its nearest template point, so a sparse template quantises the pairs:
an observed point between two template points is pulled toward one of them, and the fitted pose carries that
quantisation. Midpoints to each point's ``k`` nearest neighbours fill the surface between them (a chair's 256
points → 582, 862, 1,146, 1,449 at ``k`` = 2, 4, 6, 8) at a modest ICP cost (cKDTree queries grow with the log of
the template size).

It helps some models and not others, so it is chosen per file (docs/results/models/README.md, v0.19).

Convention: model units, the frame of the template given (the SDK's learned frame); order: the original points
first, then the midpoints.
"""
from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from equipose.core.errors import ConfigError, InvalidPointsError
from equipose.core.metadata import MAX_DENSIFY

__all__ = ["densify_template", "MAX_DENSIFY", "BRUTE_MAX_TEMPLATE"]

BRUTE_MAX_TEMPLATE = 1024   # templates up to this many points find their neighbours by brute force (compiled; a
                            # 256-point template in tens of µs, where building and querying a k-d tree takes ~0.3 ms)


def densify_template(points: np.ndarray, k: int) -> np.ndarray:
    """[M, 3] template → [M + D, 3]: the points, then the midpoint of every pair in which one point is among the
    other's ``k`` nearest neighbours (each pair once). ``k`` = 0 returns the points unchanged (as float64)."""
    Y = np.asarray(points, np.float64)
    if Y.ndim != 2 or Y.shape[1] != 3:
        raise InvalidPointsError(f"densify_template needs a [M, 3] template, got {Y.shape}")
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 0 <= k <= MAX_DENSIFY:
        raise ConfigError(f"densify k must be an int in 0..{MAX_DENSIFY} (neighbours per template point), got {k!r}")
    if k == 0 or len(Y) < 2:
        return Y
    k = min(int(k), len(Y) - 1)
    if len(Y) <= BRUTE_MAX_TEMPLATE:
        Y = np.ascontiguousarray(Y)
        low, high = _neighbour_pairs(Y, k)                                      # [D], [D]
    else:
        _, nn = cKDTree(Y).query(Y, k + 1)                                      # [M, k+1], column 0: the point
        i = np.repeat(np.arange(len(Y)), k)                                     # [M·k]
        j = nn[:, 1:].reshape(-1)                                               # [M·k]
        key = np.unique(np.minimum(i, j) * len(Y) + np.maximum(i, j))         # [D] each pair once, (low, high) order
        low, high = np.divmod(key, len(Y))                                      # [D], [D]
        keep = low != high                                                      # duplicate points: no midpoint
        low, high = low[keep], high[keep]
    return np.concatenate([Y, (Y[low] + Y[high]) / 2])                         # [M + D, 3]


@njit(cache=True, nogil=True)
def _neighbour_pairs(Y, k):
    """(low [D], high [D]): every pair (low < high) in which one point is among the other's ``k`` nearest (squared
    distance, ties to the lower index), each once, in (low, high) order."""
    M = len(Y)
    pair = np.zeros((M, M), np.bool_)
    best_d = np.empty(k)
    best_j = np.empty(k, np.int64)
    xs, ys, zs = Y[:, 0].copy(), Y[:, 1].copy(), Y[:, 2].copy()                 # [M] each: the row below vectorises
    row = np.empty(M)
    for i in range(M):
        for j in range(M):                                                      # squared distances from point i
            dx, dy, dz = xs[j] - xs[i], ys[j] - ys[i], zs[j] - zs[i]
            row[j] = dx * dx + dy * dy + dz * dz
        n = 0                                                                   # kept so far, sorted by distance
        for j in range(M):
            d = row[j]
            if j == i or (n == k and d >= best_d[k - 1]):
                continue
            p = n if n < k else k - 1                                           # insert, dropping the farthest
            while p > 0 and best_d[p - 1] > d:
                best_d[p], best_j[p] = best_d[p - 1], best_j[p - 1]
                p -= 1
            best_d[p], best_j[p] = d, j
            n = min(n + 1, k)
        for m in range(n):
            j = best_j[m]
            pair[min(i, j), max(i, j)] = True
    D = 0
    for a in range(M):
        for b in range(a + 1, M):
            D += pair[a, b]
    low, high = np.empty(D, np.int64), np.empty(D, np.int64)
    D = 0
    for a in range(M):
        for b in range(a + 1, M):
            if pair[a, b]:
                low[D], high[D] = a, b
                D += 1
    return low, high
