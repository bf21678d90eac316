"""Nearest-neighbour queries against one fixed point set: the inner loop of every ICP in the SDK.

Three backends, chosen by the reference set's size (``choose_backend``; measured side by side by
``python tools/bench/nn_backends.py``, figures in docs/benchmarks.md):

- ``"gemm"``: every query against every reference point as one float32 matrix product. With the reference points
  centred and stored as ``[−2y, |y|²]`` ([4, M]), ``[x, 1] · [−2y, |y|²]ᵀ = |x − y|² − |x|²``, so the argmin over a
  row is the nearest neighbour; one BLAS call covers all queries of all ICP starts at once. Exact up to float32
  rounding of near-ties (the returned distance is recomputed in float64 from the chosen pair).
- ``"small_gicp"``: the k-d tree of small_gicp (C++, one thread), for larger reference sets;
- ``"kdtree"``: scipy's ``cKDTree``, where small_gicp is not installed.

Convention: points are row arrays [M, 3] / [Q, 3] in one frame and one unit (the SDK uses model units); distances
are Euclidean in that unit.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from equipose.core.errors import ConfigError, InvalidPointsError

__all__ = ["NearestNeighbours", "choose_backend", "BACKENDS", "GEMM_MAX_POINTS", "GEMM_CHUNK_ENTRIES"]

BACKENDS = ("gemm", "small_gicp", "kdtree")
GEMM_MAX_POINTS = 512           # reference sets up to this size use the dense product (larger: a k-d tree)
GEMM_CHUNK_ENTRIES = 1 << 20    # [Q, M] float32 blocks of at most 4 MB per product + argmin


def _small_gicp():
    try:
        import small_gicp
    except ImportError:
        return None
    return small_gicp


def choose_backend(num_points: int) -> str:
    """The backend for a reference set of ``num_points`` points: "gemm" up to ``GEMM_MAX_POINTS``, else
    "small_gicp" (or "kdtree" where small_gicp is not installed)."""
    if num_points <= GEMM_MAX_POINTS:
        return "gemm"
    return "kdtree" if _small_gicp() is None else "small_gicp"


class NearestNeighbours:
    """Nearest neighbour in ``points`` [M, 3] of any query points.

    Args:
        points: [M ≥ 1, 3] finite reference points.
        backend: "auto" (``choose_backend``), "gemm", "small_gicp" or "kdtree".
    """

    def __init__(self, points, backend: str = "auto"):
        P = np.asarray(points, np.float64)
        if P.ndim != 2 or P.shape[1] != 3 or len(P) < 1:
            raise InvalidPointsError(f"nearest-neighbour reference points must be [M ≥ 1, 3], got {P.shape}")
        if backend not in ("auto",) + BACKENDS:
            raise ConfigError(f"nearest-neighbour backend must be 'auto' or one of {', '.join(BACKENDS)}, got "
                              f"{backend!r}")
        if backend == "small_gicp" and _small_gicp() is None:
            raise ConfigError("the small_gicp backend needs the small_gicp package: pip install small_gicp")
        self.points = P                                                         # [M, 3]
        self.backend = choose_backend(len(P)) if backend == "auto" else backend
        if self.backend == "gemm":
            self._centre = P.mean(0)                                            # [3] centring keeps float32 exact
            Pc = (P - self._centre).astype(np.float32)                          # [M, 3]
            self._table = np.ascontiguousarray(
                np.concatenate([-2.0 * Pc, np.einsum("mi,mi->m", Pc, Pc)[:, None]], 1).T)   # [4, M]
        elif self.backend == "small_gicp":
            self._gicp = _small_gicp().KdTree(P)
        else:
            self._tree = cKDTree(P)

    def __len__(self) -> int:
        return len(self.points)

    def query(self, queries) -> tuple:
        """(distance [Q] float64, index [Q] int) of the nearest reference point of each query [Q, 3] (or [..., 3]:
        the outputs then take its leading shape)."""
        q = np.asarray(queries, np.float64)
        lead = q.shape[:-1]
        q = q.reshape(-1, 3)                                                    # [Q, 3]
        if self.backend == "kdtree":
            d, i = self._tree.query(q)
            return d.reshape(lead), i.reshape(lead)
        if self.backend == "small_gicp":
            i, d2 = self._gicp.batch_nearest_neighbor_search(q)
            return np.sqrt(np.asarray(d2, np.float64)).reshape(lead), np.asarray(i, np.int64).reshape(lead)
        i = self.nearest_indices(q)                                             # [Q]
        diff = q - self.points[i]                                               # [Q, 3]
        d = np.sqrt(np.einsum("qi,qi->q", diff, diff))
        return d.reshape(lead), i.reshape(lead)

    def nearest_indices(self, queries: np.ndarray) -> np.ndarray:
        """[Q] index of the nearest reference point of each query [Q, 3] (no distances)."""
        q = np.asarray(queries, np.float64).reshape(-1, 3)
        if self.backend == "kdtree":
            return self._tree.query(q)[1]
        if self.backend == "small_gicp":
            return np.asarray(self._gicp.batch_nearest_neighbor_search(q)[0], np.int64)
        Q = len(q)
        A = np.empty((Q, 4), np.float32)                                        # [Q, 4] = [x − c, 1]
        A[:, :3] = q - self._centre
        A[:, 3] = 1.0
        step = max(1, GEMM_CHUNK_ENTRIES // self._table.shape[1])
        if Q <= step:
            return (A @ self._table).argmin(1)                                  # [Q, M] → [Q]
        return np.concatenate([(A[s:s + step] @ self._table).argmin(1) for s in range(0, Q, step)])
