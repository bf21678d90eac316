"""Hypothesis scores: the chamfer of each posed canonical reconstruction to the network input, compiled.

Convention:
    Model units (metres / scale). ``points`` [B, N, 3] is the network input (FPS-ordered, so its first ``score_points``
    points are a uniform subset); ``shape`` [B, M, 3] the canonical reconstruction Z; hypothesis j poses it as
    ``R_j @ z + t_j`` (column vectors) with ``R`` [B, J, 3, 3], ``t`` [B, J, 3]. Scores are squared distances,
    lower is better:
        one-directional (partial inputs): mean over input points x of min_z ‖R_jᵀ(x − t_j) − z‖²;
        bidirectional (complete inputs): plus the mean over reconstruction points z of min_x of the same.
    Rigid motions keep distances, so the input is moved into each hypothesis frame and Z is never posed.

Format-1 model files compute these scores inside the ONNX graph; the runtime computes them here for format-2 files,
faster than onnxruntime's MatMuls with an inner size of 5 (docs/benchmarks.md, v0.27).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError
from equipose.core.parallel import run_parts, split_ranges, workers

__all__ = ["hypothesis_scores"]

_FLOAT32_INF_BITS = 0x7F800000          # +inf as int32: non-negative float32 compare like their int32 bit patterns


@njit(cache=True, fastmath=True, nogil=True)
def _scores(points, shape, R, t, bidirectional, out):
    """``out`` [B, J] float32 = the scores (module docstring); ``points`` [B, N, 3], ``shape`` [B, M, 3] float32."""
    B, J, N, M = R.shape[0], R.shape[1], points.shape[1], shape.shape[1]
    sx, sy, sz = np.empty(M, np.float32), np.empty(M, np.float32), np.empty(M, np.float32)
    dist = np.empty(M, np.float32)                                              # one row of distances [M]
    col = np.empty(M, np.float32)                                               # per reconstruction point: min over x
    bits, col_bits = dist.view(np.int32), col.view(np.int32)                    # min of int32 bits vectorises
    one = np.empty(1, np.float32)
    one_bits = one.view(np.int32)
    for b in range(B):
        for m in range(M):
            sx[m], sy[m], sz[m] = shape[b, m, 0], shape[b, m, 1], shape[b, m, 2]
        for j in range(J):
            col_bits[:] = _FLOAT32_INF_BITS
            total = 0.0
            for i in range(N):
                px, py, pz = points[b, i, 0] - t[b, j, 0], points[b, i, 1] - t[b, j, 1], points[b, i, 2] - t[b, j, 2]
                lx = np.float32(R[b, j, 0, 0] * px + R[b, j, 1, 0] * py + R[b, j, 2, 0] * pz)   # R_jᵀ (x − t_j)
                ly = np.float32(R[b, j, 0, 1] * px + R[b, j, 1, 1] * py + R[b, j, 2, 1] * pz)
                lz = np.float32(R[b, j, 0, 2] * px + R[b, j, 1, 2] * py + R[b, j, 2, 2] * pz)
                for m in range(M):
                    dx, dy, dz = sx[m] - lx, sy[m] - ly, sz[m] - lz
                    dist[m] = dx * dx + dy * dy + dz * dz
                nearest = np.int32(_FLOAT32_INF_BITS)
                for m in range(M):
                    nearest = min(nearest, bits[m])
                if bidirectional:
                    for m in range(M):
                        col_bits[m] = min(col_bits[m], bits[m])
                one_bits[0] = nearest
                total += one[0]
            score = total / N
            if bidirectional:
                back = 0.0
                for m in range(M):
                    back += col[m]
                score += back / M
            out[b, j] = score


def hypothesis_scores(points: np.ndarray, shape: np.ndarray, R: np.ndarray, t: np.ndarray, *,
                      bidirectional: bool, score_points: int = 0) -> np.ndarray:
    """Chamfer scores of the J hypotheses of each input → [B, J] float32 (module docstring).

    ``score_points`` > 0 scores with the first ``score_points`` input points only (the model's
    ``model_config.score_points``); 0 uses all N.
    """
    points = np.asarray(points, np.float32)
    shape = np.asarray(shape, np.float32)
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64)
    if points.ndim != 3 or points.shape[2] != 3 or shape.ndim != 3 or shape.shape[2] != 3:
        raise InvalidPointsError(f"points and shape must be [B, N, 3] and [B, M, 3], got {points.shape}, {shape.shape}")
    B = points.shape[0]
    if shape.shape[0] != B or R.shape[:1] + R.shape[2:] != (B, 3, 3) or t.shape != (B, R.shape[1], 3):
        raise InvalidPointsError(f"hypotheses must be R [B, J, 3, 3] and t [B, J, 3] for B = {B}, got {R.shape}, "
                                 f"{t.shape}; shape {shape.shape}")
    if 0 < score_points < points.shape[1]:
        points = points[:, :score_points]                                       # [B, N', 3]
    points, shape = np.ascontiguousarray(points), np.ascontiguousarray(shape)
    parts = split_ranges(R.shape[1], workers())                                # hypotheses [a, b) per part
    outs = run_parts(_part_scores, [(points, shape, np.ascontiguousarray(R[:, a:b]), np.ascontiguousarray(t[:, a:b]),
                                     bool(bidirectional)) for a, b in parts])  # side by side (core.parallel)
    return outs[0] if len(outs) == 1 else np.concatenate(outs, axis=1)         # [B, J]


def _part_scores(points, shape, R, t, bidirectional) -> np.ndarray:
    out = np.empty(R.shape[:2], np.float32)                                     # [B, J']
    _scores(points, shape, R, t, bidirectional, out)
    return out
