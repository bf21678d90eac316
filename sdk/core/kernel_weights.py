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

Format-4 files take, for some layers (the shipped files: layer 0), the kernel weights already summed per kernel class
instead (``CLASS_MATRIX``: for the descriptor along vertex v, the classes centre, same vertex, near ring, far ring,
antipode): ``class_weights_0`` [B, points_out, 12, 5] (the lifting layer, summed over the neighbours too) and, for
l ≥ 1, ``class_weights_<l>`` [12, B · points_out, 5, neighbours] (vertex-major, the layout of the graph's
neighbourhood MatMul), with the same ``neighbour_rows_<l>``: the graph's constant class MatMul of that layer and the
sum or transposes after it go (docs/benchmarks.md, v0.53).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError
from equipose.core.icosahedral import VERTEX_CLASS, kernel_points
from equipose.core.neighbourhoods import input_name, neighbourhood_specs

__all__ = ["WEIGHTS_PREFIX", "CLASS_PREFIX", "ROWS_PREFIX", "QUOTIENT_KERNEL_POINTS", "KERNEL_CLASSES",
           "CLASS_MATRIX", "kernel_aug", "layer_kernel_aug", "weights_name", "class_name", "rows_name",
           "kernel_input_names", "kernel_inputs"]

WEIGHTS_PREFIX = "kernel_weights_"          # format-3 graph input: the kernel weights of layer l (+ str(l))
CLASS_PREFIX = "class_weights_"             # format-4 graph input: layer l's kernel weights summed per class
ROWS_PREFIX = "neighbour_rows_"             # graph input: the feature rows layer l gathers (ROWS_PREFIX + str(l))
QUOTIENT_KERNEL_POINTS = 13                 # centre + the 12 icosahedron vertices
VERTICES = 12
KERNEL_CLASSES = 5                          # centre, same vertex, near ring, far ring, antipode


def _class_matrix() -> np.ndarray:
    """[12 · 5, 13] float32 0/1 (read only): row v · 5 + c sums the kernel points of class c seen from vertex v."""
    m = np.zeros((VERTICES, KERNEL_CLASSES, QUOTIENT_KERNEL_POINTS), np.float32)
    m[:, 0, 0] = 1.0                                                            # the centre
    for v in range(VERTICES):
        for u in range(VERTICES):
            m[v, 1 + int(VERTEX_CLASS[v, u]), u + 1] = 1.0                      # same / near / far / antipode
    m = m.reshape(VERTICES * KERNEL_CLASSES, QUOTIENT_KERNEL_POINTS)
    m.flags.writeable = False
    return m


CLASS_MATRIX = _class_matrix()
_NEAR = np.array([np.flatnonzero(VERTEX_CLASS[v] == 1) for v in range(VERTICES)], np.int64)     # [12, 5]
_ANTIPODE = np.array([np.flatnonzero(VERTEX_CLASS[v] == 3)[0] for v in range(VERTICES)], np.int64)   # [12]


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


def class_name(layer: int) -> str:
    return f"{CLASS_PREFIX}{layer}"


def rows_name(layer: int) -> str:
    return f"{ROWS_PREFIX}{layer}"


def kernel_input_names(layers, classes=()) -> list:
    """The graph inputs after ``points`` for ``layers`` (``ModelConfig.layers``), in order: each layer's kernel
    weights (``class_weights_<l>`` for the layers in ``classes``, else ``kernel_weights_<l>``), then each feature
    layer's rows."""
    return [class_name(i) if i in classes else weights_name(i) for i in range(len(layers))] + \
        [rows_name(i) for i in range(1, len(layers))]


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


_TILE = 32                                      # centres whose weights ``_class_weights`` holds at once


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _class_weights(x, centre, nbh, centres, k, aug, near, anti, out):
    """``out`` [12, B · centres, 5, k] float32: ``_weights`` of centre p summed per kernel class seen from vertex v,
    ``CLASS_MATRIX`` @ weights, written vertex-major. ``near`` [12, 5] / ``anti`` [12]: each vertex's near ring and
    antipode (the far ring of v is the near ring of its antipode). Works in tiles of ``_TILE`` centres, so that each
    vertex's rows are written as one sequential run per tile."""
    w = np.empty((_TILE, QUOTIENT_KERNEL_POINTS, k), np.float32)               # [tile, 13, k] the tile's weights
    o = out.reshape(-1, k)                                                      # rows (v, b · centres + p, class)
    per_vertex = out.shape[1] * KERNEL_CLASSES
    dx, dy, dz, d2 = (np.empty(k, np.float32), np.empty(k, np.float32), np.empty(k, np.float32),
                      np.empty(k, np.float32))
    total = x.shape[0] * centres
    for start in range(0, total, _TILE):
        size = min(_TILE, total - start)
        for t in range(size):
            b, p = (start + t) // centres, (start + t) % centres
            mx, my, mz = centre[b, 0], centre[b, 1], centre[b, 2]
            cx, cy, cz = x[b, p, 0] - mx, x[b, p, 1] - my, x[b, p, 2] - mz
            for n in range(k):
                j = nbh[b, p, n]
                dx[n], dy[n], dz[n] = (x[b, j, 0] - mx) - cx, (x[b, j, 1] - my) - cy, (x[b, j, 2] - mz) - cz
                d2[n] = dx[n] * dx[n] + dy[n] * dy[n] + dz[n] * dz[n]
            for r in range(QUOTIENT_KERNEL_POINTS):
                a0, a1, a2, a3, a4 = aug[r, 0], aug[r, 1], aug[r, 2], aug[r, 3], aug[r, 4]
                for n in range(k):
                    w[t, r, n] = max(a0 * dx[n] + a1 * dy[n] + a2 * dz[n] + a3 * d2[n] + a4, np.float32(0.0))
        for v in range(VERTICES):                       # one loop per class row: contiguous, vectorised stores
            same, opposite = v + 1, anti[v] + 1
            i0, i1, i2, i3, i4 = near[v, 0] + 1, near[v, 1] + 1, near[v, 2] + 1, near[v, 3] + 1, near[v, 4] + 1
            for t in range(size):
                row = v * per_vertex + (start + t) * KERNEL_CLASSES
                far = anti[v] * per_vertex + (start + t) * KERNEL_CLASSES + 3  # v's near ring: its antipode's far
                for n in range(k):
                    o[row, n] = w[t, 0, n]
                for n in range(k):
                    o[row + 1, n] = w[t, same, n]
                for n in range(k):
                    ring = w[t, i0, n] + w[t, i1, n] + w[t, i2, n] + w[t, i3, n] + w[t, i4, n]
                    o[row + 2, n] = ring
                    o[far, n] = ring
                for n in range(k):
                    o[row + 4, n] = w[t, opposite, n]


@njit(cache=True, nogil=True, fastmath=True, error_model="numpy")
def _class_sums(x, centre, nbh, centres, k, aug, near, anti, out):
    """``out`` [B, centres, 12, 5] float32: ``_class_weights`` summed over the k neighbours (the lifting layer,
    whose input features are constant ones)."""
    s = np.empty(QUOTIENT_KERNEL_POINTS, np.float32)                            # [13] one centre's summed weights
    d = np.empty((4, k), np.float32)                                            # offsets and their squared norms
    for b in range(x.shape[0]):
        mx, my, mz = centre[b, 0], centre[b, 1], centre[b, 2]
        for p in range(centres):
            cx, cy, cz = x[b, p, 0] - mx, x[b, p, 1] - my, x[b, p, 2] - mz
            for n in range(k):
                j = nbh[b, p, n]
                d[0, n] = (x[b, j, 0] - mx) - cx
                d[1, n] = (x[b, j, 1] - my) - cy
                d[2, n] = (x[b, j, 2] - mz) - cz
                d[3, n] = d[0, n] * d[0, n] + d[1, n] * d[1, n] + d[2, n] * d[2, n]
            for r in range(QUOTIENT_KERNEL_POINTS):
                a0, a1, a2, a3, a4 = aug[r, 0], aug[r, 1], aug[r, 2], aug[r, 3], aug[r, 4]
                acc = np.float32(0.0)
                for n in range(k):
                    acc += max(a0 * d[0, n] + a1 * d[1, n] + a2 * d[2, n] + a3 * d[3, n] + a4, np.float32(0.0))
                s[r] = acc
            for v in range(VERTICES):
                a = anti[v]
                out[b, p, v, 0] = s[0]
                out[b, p, v, 1] = s[v + 1]
                out[b, p, v, 2] = s[near[v, 0] + 1] + s[near[v, 1] + 1] + s[near[v, 2] + 1] + s[near[v, 3] + 1] + \
                    s[near[v, 4] + 1]
                out[b, p, v, 3] = s[near[a, 0] + 1] + s[near[a, 1] + 1] + s[near[a, 2] + 1] + s[near[a, 3] + 1] + \
                    s[near[a, 4] + 1]
                out[b, p, v, 4] = s[a + 1]


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


def _centred(points: np.ndarray) -> tuple:
    x = np.ascontiguousarray(points, np.float32)
    if x.ndim != 3 or x.shape[2] != 3:
        raise InvalidPointsError(f"points must be [B, N, 3], got {x.shape}")
    return x, x.mean(axis=1, dtype=np.float32)                                 # [B, N, 3], [B, 3] as the graph centres


def kernel_inputs(points: np.ndarray, layers, neighbourhoods: dict, classes=()) -> dict:
    """The kernel inputs ``{name: array}`` (module docstring) of ``points`` [B, N, 3] for ``layers``
    (``ModelConfig.layers`` of a quotient preset), given ``neighbourhoods`` ``{input_name(spec): [B, centres, k]}``
    (``equipose.core.neighbourhoods.neighbourhoods``): each layer's kernel weights (format 3), or for the layers in
    ``classes`` the weights summed per kernel class (format 4), and each feature layer's rows."""
    x, centre = _centred(points)
    B = x.shape[0]
    out = {}
    for i, (L, (nbh_name, aug)) in enumerate(zip(layers, _plan(tuple(layers)))):
        nbh = neighbourhoods[nbh_name]                                          # [B, centres, k] int64
        args = (x, centre, nbh, L.points_out, L.neighbours, aug)
        if i not in classes:
            name = weights_name(i)
            w = np.empty((B, L.points_out, QUOTIENT_KERNEL_POINTS, L.neighbours), np.float32)
            _weights(*args, w)                                                  # [B, P2, 13, nn]
        elif i == 0:                                                            # lifting: summed over neighbours
            name = class_name(i)
            w = np.empty((B, L.points_out, VERTICES, KERNEL_CLASSES), np.float32)
            _class_sums(*args, _NEAR, _ANTIPODE, w)                             # [B, P2, 12, 5]
        else:
            name = class_name(i)
            w = np.empty((VERTICES, B * L.points_out, KERNEL_CLASSES, L.neighbours), np.float32)
            _class_weights(*args, _NEAR, _ANTIPODE, w)                          # [12, B·P2, 5, nn]
        out[name] = w
        if i:
            rows = np.empty(B * L.points_out * L.neighbours, np.int64)
            _rows(nbh, L.points_out, L.neighbours, L.points_in, rows)           # [B·P2·nn]
            out[rows_name(i)] = rows
    return out
