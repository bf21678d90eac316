"""The kernel weights of the network's point convolutions, computed outside the graph (compiled).

Convention:
    Points [B, N, 3] float32 model units, FPS-ordered (layer l's support is the prefix ``points[:, :points_in]``, its
    centres the prefix ``[:, :points_out]``), centred here at their mean as the graph centres them. Layer l reads its
    neighbourhood ``nbh[:, :points_out, :neighbours]`` (``equipose.core.neighbourhoods``: indices into the support,
    nearest first).
    A kernel weight is the hat correlation relu(1 − ‖d − κ‖² / σ) of a neighbour's offset d = x_n − x_p (model units)
    with kernel point κ of the layer (``LayerSpec.kernel_radius``, ``LayerSpec.sigma``), written as one product of the
    row [2κ/σ, −1/σ, 1 − ‖κ‖²/σ] (``kernel_aug``) with [d, ‖d‖², 1].

Format-3 model files (quotient presets) take, per layer l, ``kernel_weights_<l>`` float32 [B, points_out, 13,
neighbours] and, for a layer with input features (l ≥ 1), ``neighbour_rows_<l>`` int64 [B · points_out · neighbours]
= b · points_in + the neighbour's index (the rows of the layer's input features, batch-major, that the graph gathers),
instead of the neighbourhoods themselves: about 75 graph nodes fewer, computed here in a few tens of µs
(docs/benchmarks.md, v0.30).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError
from equipose.core.icosahedral import kernel_points
from equipose.core.neighbourhoods import input_name, neighbourhood_specs

__all__ = ["WEIGHTS_PREFIX", "ROWS_PREFIX", "QUOTIENT_KERNEL_POINTS", "kernel_aug", "layer_kernel_aug",
           "weights_name", "rows_name", "kernel_input_names", "kernel_inputs"]

WEIGHTS_PREFIX = "kernel_weights_"          # graph input: the kernel weights of layer l (WEIGHTS_PREFIX + str(l))
ROWS_PREFIX = "neighbour_rows_"             # graph input: the feature rows layer l gathers (ROWS_PREFIX + str(l))
QUOTIENT_KERNEL_POINTS = 13                 # centre + the 12 icosahedron vertices


def kernel_aug(kernel: np.ndarray, sigma: float) -> np.ndarray:
    """Kernel points [R, 3] (model units) → [R, 5] float32 rows [2κ/σ, −1/σ, 1 − ‖κ‖²/σ]: the hat weight
    1 − ‖d − κ‖²/σ of an offset d is the row times [d, ‖d‖², 1]."""
    kernel = np.asarray(kernel, np.float64)
    aug = np.concatenate([2.0 * kernel / sigma, np.full((len(kernel), 1), -1.0 / sigma),
                          1.0 - (kernel ** 2).sum(1, keepdims=True) / sigma], 1)          # [R, 5]
    return aug.astype(np.float32)


@lru_cache(maxsize=64)
def layer_kernel_aug(spec) -> np.ndarray:
    """[13, 5] float32: ``kernel_aug`` of a quotient layer's 13 symmetric kernel points (``LayerSpec``; cached, read
    only)."""
    aug = kernel_aug(kernel_points(QUOTIENT_KERNEL_POINTS, spec.kernel_radius), spec.sigma)
    aug.flags.writeable = False
    return aug


def weights_name(layer: int) -> str:
    return f"{WEIGHTS_PREFIX}{layer}"


def rows_name(layer: int) -> str:
    return f"{ROWS_PREFIX}{layer}"


def kernel_input_names(layers) -> list:
    """The format-3 graph inputs after ``points`` for ``layers`` (``ModelConfig.layers``), in order: each layer's
    weights, then each feature layer's rows."""
    return [weights_name(i) for i in range(len(layers))] + [rows_name(i) for i in range(1, len(layers))]


@njit(cache=True, nogil=True, fastmath=True)
def _weights(x, centre, nbh, centres, k, aug, out):
    """``out`` [B, centres, R, k] float32 = relu(aug @ [d, ‖d‖², 1]) for d = x[b, nbh[b, p, n]] − x[b, p], with
    ``x`` [B, N, 3] centred at ``centre`` [B, 3] first (as the graph centres its input)."""
    R = aug.shape[0]
    dx, dy, dz, d2 = (np.empty(k, np.float32), np.empty(k, np.float32), np.empty(k, np.float32),
                      np.empty(k, np.float32))
    for b in range(x.shape[0]):
        mx, my, mz = centre[b, 0], centre[b, 1], centre[b, 2]
        for p in range(centres):
            cx, cy, cz = x[b, p, 0] - mx, x[b, p, 1] - my, x[b, p, 2] - mz
            for n in range(k):                                                  # the k offsets of centre p
                j = nbh[b, p, n]
                dx[n], dy[n], dz[n] = (x[b, j, 0] - mx) - cx, (x[b, j, 1] - my) - cy, (x[b, j, 2] - mz) - cz
                d2[n] = dx[n] * dx[n] + dy[n] * dy[n] + dz[n] * dz[n]
            for r in range(R):                                                  # contiguous rows of k weights
                a0, a1, a2, a3, a4 = aug[r, 0], aug[r, 1], aug[r, 2], aug[r, 3], aug[r, 4]
                for n in range(k):
                    out[b, p, r, n] = max(a0 * dx[n] + a1 * dy[n] + a2 * dz[n] + a3 * d2[n] + a4, np.float32(0.0))


@njit(cache=True, nogil=True)
def _rows(nbh, centres, k, support, out):
    """``out`` [B · centres · k] int64 = b · support + nbh[b, p, n], batch-major."""
    i = 0
    for b in range(nbh.shape[0]):
        for p in range(centres):
            for n in range(k):
                out[i] = b * support + nbh[b, p, n]
                i += 1


@lru_cache(maxsize=64)
def _plan(layers: tuple) -> tuple:
    """Per layer: (its neighbourhood's input name, its ``kernel_aug``)."""
    specs = {s.support: s for s in neighbourhood_specs(layers)}
    return tuple((input_name(specs[L.points_in]), layer_kernel_aug(L)) for L in layers)


def kernel_inputs(points: np.ndarray, layers, neighbourhoods: dict) -> dict:
    """The format-3 kernel inputs ``{name: array}`` (module docstring) of ``points`` [B, N, 3] for ``layers``
    (``ModelConfig.layers`` of a quotient preset), given ``neighbourhoods`` ``{input_name(spec): [B, centres, k]}``
    (``equipose.core.neighbourhoods.neighbourhoods``)."""
    x = np.ascontiguousarray(points, np.float32)
    if x.ndim != 3 or x.shape[2] != 3:
        raise InvalidPointsError(f"points must be [B, N, 3], got {x.shape}")
    centre = x.mean(axis=1, dtype=np.float32)                                  # [B, 3] as the graph centres
    out = {}
    for i, (L, (nbh_name, aug)) in enumerate(zip(layers, _plan(tuple(layers)))):
        nbh = neighbourhoods[nbh_name]                                          # [B, centres, k] int64
        w = np.empty((x.shape[0], L.points_out, QUOTIENT_KERNEL_POINTS, L.neighbours), np.float32)
        _weights(x, centre, nbh, L.points_out, L.neighbours, aug, w)            # [B, P2, 13, nn]
        out[weights_name(i)] = w
        if i:
            rows = np.empty(x.shape[0] * L.points_out * L.neighbours, np.int64)
            _rows(nbh, L.points_out, L.neighbours, L.points_in, rows)           # [B·P2·nn]
            out[rows_name(i)] = rows
    return out
