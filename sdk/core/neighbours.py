"""Nearest-neighbour queries against one fixed point set, from Python (visibility, frame priors, tools).

Backends:

- ``"compiled"`` (the default): ``equipose.core.nearest`` — brute force up to ``BRUTE_MAX_POINTS`` reference points,
  a k-d tree above; the same search the compiled ICP runs inside its loop;
- ``"kdtree"``: scipy's ``cKDTree`` (a reference for tests and ``python tools/bench/nn_backends.py``).

Convention: points are row arrays [M, 3] / [Q, 3] in one frame and one unit (the SDK uses model units); distances
are Euclidean in that unit, computed in float64 from the chosen pair.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from equipose.core.errors import ConfigError, InvalidPointsError
from equipose.core.nearest import BRUTE_MAX_POINTS, build_index, nearest_all

__all__ = ["NearestNeighbours", "BACKENDS", "BRUTE_MAX_POINTS"]

BACKENDS = ("compiled", "kdtree")


class NearestNeighbours:
    """Nearest neighbour in ``points`` [M, 3] of any query points.

    Args:
        points: [M ≥ 1, 3] finite reference points.
        backend: "compiled" or "kdtree".
        brute_max: (compiled) sets of at most this many points are searched by brute force, larger ones by a tree.
    """

    def __init__(self, points, backend: str = "compiled", brute_max: int = BRUTE_MAX_POINTS):
        P = np.ascontiguousarray(points, np.float64)
        if P.ndim != 2 or P.shape[1] != 3 or len(P) < 1:
            raise InvalidPointsError(f"nearest-neighbour reference points must be [M ≥ 1, 3], got {P.shape}")
        if backend not in BACKENDS:
            raise ConfigError(f"nearest-neighbour backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
        self.points, self.backend = P, backend                                  # [M, 3]
        if backend == "compiled":
            self._index = build_index(P[None], int(brute_max))
        else:
            self._tree = cKDTree(P)

    def __len__(self) -> int:
        return len(self.points)

    def query(self, queries, guess=None) -> tuple:
        """(distance [Q] float64, index [Q] int) of the nearest reference point of each query [Q, 3] (or [..., 3]:
        the outputs then take its leading shape). ``guess``: optional likely answers [Q] (e.g. the previous
        iteration's), which speed up the compiled tree; the result is exact either way."""
        q = np.asarray(queries, np.float64)
        i = self.nearest_indices(q, guess)                                      # [Q]
        diff = q.reshape(-1, 3) - self.points[i]                                # [Q, 3]
        return np.sqrt(np.einsum("qi,qi->q", diff, diff)).reshape(q.shape[:-1]), i.reshape(q.shape[:-1])

    def nearest_indices(self, queries, guess=None) -> np.ndarray:
        """[Q] index of the nearest reference point of each query [Q, 3] (no distances); ``guess`` as in ``query``."""
        q = np.ascontiguousarray(np.asarray(queries, np.float64).reshape(-1, 3))
        if self.backend == "kdtree":
            return self._tree.query(q)[1]
        g = np.zeros(0, np.int64) if guess is None else np.ascontiguousarray(guess, np.int64).reshape(-1)
        if len(g) and len(g) != len(q):
            raise InvalidPointsError(f"guess must give one index per query ({len(q)}), got {len(g)}")
        out = np.empty(len(q), np.int64)
        nearest_all(self._index, q, g, out)
        return out
