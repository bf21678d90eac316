"""The network's point neighbourhoods: which k-nearest-neighbour sets a model needs, and computing them (compiled).

Convention:
    Points [B, N, 3] float32 model units, FPS-ordered, so every layer's support is the prefix ``points[:, :support]``
    and its centres the prefix ``[:, :centres]``. A neighbourhood is int64 [B, centres, k]: the indices (into the
    support) of each centre's k nearest support points, nearest first; ties go to the lower index.
    Layers sharing a support share one neighbourhood over the most centres and neighbours any of them needs; a layer
    taking fewer neighbours uses its nearest-first prefix.

Format-2 model files take the neighbourhoods as graph inputs named ``neighbours_<support>`` (``input_name``), which
the runtime computes here, faster than onnxruntime's TopKs over the distance matrices (docs/benchmarks.md, v0.27).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError

__all__ = ["INPUT_PREFIX", "NeighbourhoodSpec", "neighbourhood_specs", "input_name", "nearest_neighbourhoods",
           "neighbourhoods"]

INPUT_PREFIX = "neighbours_"                    # graph input of a neighbourhood: INPUT_PREFIX + its support size


@dataclass(frozen=True)
class NeighbourhoodSpec:
    """One shared neighbourhood: ``centres`` first points, each with its ``k`` nearest among the first ``support``;
    ``ordered`` when some layer reads a nearest-first prefix of it (then its order matters, otherwise only its set)."""
    support: int
    centres: int
    k: int
    ordered: bool


def neighbourhood_specs(layers) -> list:
    """The distinct neighbourhoods of a model's layers (``ModelConfig.layers``: ``points_in``, ``points_out``,
    ``neighbours``), one per support size, in the order the layers first use them."""
    need: dict = {}
    for L in layers:
        centres, k = need.get(L.points_in, (0, 0))
        need[L.points_in] = (max(centres, L.points_out), max(k, L.neighbours))
    prefix = {L.points_in for L in layers if L.neighbours < need[L.points_in][1]}
    return [NeighbourhoodSpec(support, centres, k, support in prefix) for support, (centres, k) in need.items()]


def input_name(spec: NeighbourhoodSpec) -> str:
    """The graph input that carries ``spec``'s neighbourhood."""
    return f"{INPUT_PREFIX}{spec.support}"


_NO_KEY = np.int64(0x7FFFFFFFFFFFFFFF)


@njit(cache=True, fastmath=True, nogil=True)
def _knn(points, support, centres, k, out):
    """``out`` [B, centres, k] int64 = the k nearest of the first ``support`` points for each of the first
    ``centres`` points of ``points`` [B, N, 3] float32, nearest first (squared float32 distances, lower index on ties).

    Each candidate's key is its distance's int32 bit pattern (non-negative floats order like their bits) above its
    index; k rounds of a vectorised minimum over the keys pick the neighbours in order: branch-free, unlike inserting
    candidates into a sorted top-k, whose branches the CPU cannot predict (docs/benchmarks.md, v0.27)."""
    xs, ys, zs = np.empty(support, np.float32), np.empty(support, np.float32), np.empty(support, np.float32)
    dist = np.empty(support, np.float32)
    bits = dist.view(np.int32)
    keys = np.empty(support, np.int64)
    for b in range(points.shape[0]):
        for m in range(support):
            xs[m], ys[m], zs[m] = points[b, m, 0], points[b, m, 1], points[b, m, 2]
        for c in range(centres):
            cx, cy, cz = xs[c], ys[c], zs[c]
            for m in range(support):
                dx, dy, dz = xs[m] - cx, ys[m] - cy, zs[m] - cz
                dist[m] = dx * dx + dy * dy + dz * dz
            for m in range(support):
                keys[m] = (np.int64(bits[m]) << 32) | m
            for j in range(k):
                best = _NO_KEY
                for m in range(support):
                    best = min(best, keys[m])
                nearest = best & 0xFFFFFFFF
                out[b, c, j] = nearest
                keys[nearest] = _NO_KEY


def nearest_neighbourhoods(points: np.ndarray, spec: NeighbourhoodSpec) -> np.ndarray:
    """The neighbourhood ``spec`` of ``points`` [B, N, 3] (model units) → int64 [B, centres, k] (module docstring)."""
    x = np.ascontiguousarray(points, np.float32)
    if x.ndim != 3 or x.shape[2] != 3:
        raise InvalidPointsError(f"points must be [B, N, 3], got {x.shape}")
    if not 1 <= spec.k <= spec.support <= x.shape[1] or not 1 <= spec.centres <= spec.support:
        raise InvalidPointsError(f"neighbourhood {spec} does not fit {x.shape[1]} points")
    out = np.empty((x.shape[0], spec.centres, spec.k), np.int64)               # [B, centres, k]
    _knn(x, spec.support, spec.centres, spec.k, out)
    return out


def neighbourhoods(points: np.ndarray, specs) -> dict:
    """``{input_name(spec): [B, centres, k] int64}`` for every spec of ``specs`` (``neighbourhood_specs``)."""
    return {input_name(s): nearest_neighbourhoods(points, s) for s in specs}
