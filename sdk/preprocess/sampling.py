"""Model input: farthest-point ordering, centring and scaling of metric object points.

Convention: ``points_m`` [P, 3] metres (camera frame) → ``model_points`` [N, 3] float32 model units,
``(p − centre) / scale``, FPS-ordered (nested prefixes).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from equipose.core.errors import InvalidPointsError, TooFewPointsError
from equipose.core.geometry import farthest_point_order
from equipose.preprocess.validate import check_points

__all__ = ["MIN_POINTS", "PreparedPoints", "fps_order", "prepare_points"]

MIN_POINTS = 64                 # fewer points than this after the crop cannot give a meaningful pose


@dataclass
class PreparedPoints:
    """Model input for one object and what maps the outputs back to metres.

    Attributes:
        model_points: [N, 3] float32 model units, FPS-ordered, centred: ``(p_m − centre_m) / scale``.
        centre_m: [3] float64 metres, camera frame (subtracted before scaling).
        scale: metres per model unit (from the model metadata).
        order: [N] int64 indices into the metric points that were passed in (FPS order; repeats when P < N).
    Map back: ``x_m = x_model · scale + centre_m`` (points and translations; rotations are unchanged).
    """
    model_points: np.ndarray
    centre_m: np.ndarray
    scale: float
    order: np.ndarray

    def to_metres(self, x_model: np.ndarray) -> np.ndarray:
        """[..., 3] model units → [..., 3] metres, camera frame."""
        return np.asarray(x_model, np.float64) * self.scale + self.centre_m


def fps_order(points: np.ndarray, n: int, start: int = 0) -> np.ndarray:
    """``geometry.farthest_point_order`` with the SDK's typed error. Convention: [P, 3] → indices [n] (nested)."""
    if len(points) == 0:
        raise TooFewPointsError("farthest-point ordering got no points")
    return farthest_point_order(points, n, start=start)


def prepare_points(points_m, num_points: int, scale: float, *, min_points: int = MIN_POINTS,
                   max_fps_input: int = 4096) -> PreparedPoints:
    """Metric object points → the model's FPS-ordered, centred, scaled input.

    Convention: ``points_m`` [P, 3] metres (camera frame). Output ``model_points`` [N, 3] float32 model units,
    ``(p − centre) / scale`` with ``centre`` the centroid in metres; FPS-ordered (nested prefixes, as the model's
    in-graph downsampling expects), starting from the point farthest from the centroid. When P > ``max_fps_input`` the
    points are first thinned with a regular stride (deterministic). When P < N the FPS order repeats (wraps).
    Raises ``InvalidPointsError`` (shape, NaN/Inf), ``TooFewPointsError`` (P < ``min_points``).
    """
    p = check_points(points_m)                                                  # [P, 3] float64 m
    if not (isinstance(num_points, (int, np.integer)) and num_points > 0):
        raise InvalidPointsError(f"num_points must be a positive int, got {num_points!r}")
    if not (math.isfinite(float(scale)) and float(scale) > 0):
        raise InvalidPointsError(f"scale must be positive (metres per model unit), got {scale!r}")
    P = len(p)
    if P < min_points:
        raise TooFewPointsError(f"{P} points given, need at least {min_points}; enlarge the crop")
    base = np.arange(P)
    if P > max_fps_input:
        base = base[:: int(math.ceil(P / max_fps_input))]                       # [P'] regular thinning
    q = p[base]                                                                 # [P', 3]
    centre = q.mean(axis=0)                                                     # [3] m
    qc = ((q - centre) / float(scale)).astype(np.float32)                       # [P', 3] model units
    start = int(np.argmax(np.einsum("ij,ij->i", qc, qc)))
    idx = fps_order(qc, int(num_points), start=start)                          # [N]
    return PreparedPoints(model_points=np.ascontiguousarray(qc[idx]), centre_m=centre, scale=float(scale),
                          order=base[idx])
