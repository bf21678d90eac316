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
from scipy.spatial import cKDTree

from equipose.core.errors import ConfigError, InvalidPointsError
from equipose.core.metadata import MAX_DENSIFY

__all__ = ["densify_template", "MAX_DENSIFY"]


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
    _, nn = cKDTree(Y).query(Y, k + 1)                                          # [M, k+1], column 0: the point
    i = np.repeat(np.arange(len(Y)), k)                                         # [M·k]
    j = nn[:, 1:].reshape(-1)                                                   # [M·k]
    key = np.unique(np.minimum(i, j) * len(Y) + np.maximum(i, j))             # [D] each pair once, (low, high) order
    low, high = np.divmod(key, len(Y))                                          # [D], [D]
    keep = low != high                                                          # duplicate points: no midpoint
    return np.concatenate([Y, (Y[low[keep]] + Y[high[keep]]) / 2])            # [M + D, 3]
