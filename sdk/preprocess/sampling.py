"""Model input: farthest-point ordering, centring and scaling of metric object points.

Convention: ``points_m`` [P, 3] metres (camera frame) → ``model_points`` [N, 3] float32 model units,
``(p − centre) / scale``, FPS-ordered (nested prefixes).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError, TooFewPointsError
from equipose.core.geometry import farthest_point_order
from equipose.preprocess.validate import PLAUSIBLE_DEPTH_M, check_points

__all__ = ["MIN_POINTS", "MIN_DISTINCT", "SPREAD_RANGE", "PreparedPoints", "check_spread", "fps_order", "prepare_points"]

MIN_POINTS = 64                 # fewer points than this after the crop cannot give a meaningful pose
MIN_DISTINCT = 16               # fewer distinct positions than this: repeated points, not a surface
SPREAD_RANGE = (0.01, 100.0)    # accepted RMS radius of an object, model units (trained objects: ≈ 0.5–1)
MIN_FLATNESS = 1e-3             # second / first principal spread below this: collinear points


@dataclass
class PreparedPoints:
    """Model input for one object and what maps the outputs back to metres.

    Attributes:
        model_points: [N, 3] float32 model units, FPS-ordered, centred: ``(p_m − centre_m) / scale``.
        centre_m: [3] float64 metres, camera frame (subtracted before scaling).
        scale: metres per model unit (from the model metadata).
        order: [N] int64 indices into the metric points that were passed in (FPS order; repeats when P < N).
        cloud: [P', 3] float32 model units, centred like ``model_points``: every point FPS chose from (the input,
            thinned when longer than ``max_fps_input``), for stages that want more of the surface than N points.
    Map back: ``x_m = x_model · scale + centre_m`` (points and translations; rotations are unchanged).
    """
    model_points: np.ndarray
    centre_m: np.ndarray
    scale: float
    order: np.ndarray
    cloud: np.ndarray | None = None

    def to_metres(self, x_model: np.ndarray) -> np.ndarray:
        """[..., 3] model units → [..., 3] metres, camera frame."""
        return np.asarray(x_model, np.float64) * self.scale + self.centre_m

    @property
    def camera(self) -> np.ndarray:
        """[3] float64 model units: where the camera sits in the centred frame of ``model_points`` (−centre_m / scale)."""
        return -np.asarray(self.centre_m, np.float64) / float(self.scale)


def check_spread(points_model: np.ndarray, centre_m: np.ndarray, scale: float) -> None:
    """Refuse degenerate or wrongly scaled object points.

    Convention: ``points_model`` [P, 3] centred model units (``(p − centre) / scale``), ``centre_m`` [3] metres. The RMS
    radius must lie in ``SPREAD_RANGE`` model units (the networks are trained on objects of radius ≈ 0.5–1), the cloud
    must not be a line (second principal axis ≥ ``MIN_FLATNESS`` × the first; planar views are fine) and the centre
    must be nearer than ``PLAUSIBLE_DEPTH_M[1]``. Raises ``InvalidPointsError``.
    """
    radius, scatter = _spread(np.ascontiguousarray(points_model, np.float64))   # RMS radius, [3, 3] Σ x xᵀ
    dist = float(np.linalg.norm(centre_m))
    if dist > PLAUSIBLE_DEPTH_M[1] or radius > SPREAD_RANGE[1]:
        raise InvalidPointsError(
            f"points centred {dist:.4g} m from the camera with an RMS radius of {radius * scale:.4g} m are implausible "
            f"for this model (objects of about {scale:.3g} m): they look like millimetres — pass metres "
            "(points_mm / 1000)")
    if not radius >= SPREAD_RANGE[0]:
        raise InvalidPointsError(
            f"the points span only {radius * scale:.3g} m (RMS radius) while this model expects objects of about "
            f"{scale:.3g} m: the cloud is degenerate (a point, or wrongly scaled) — check the crop and the units")
    sv = np.sqrt(np.clip(np.linalg.eigvalsh(scatter), 0, None))[::-1]         # [3] principal spreads
    if sv[1] < MIN_FLATNESS * sv[0]:
        raise InvalidPointsError(f"the points lie on a line (principal spreads {np.round(sv * scale, 6).tolist()} m); "
                                 "a pose needs a surface — check the crop or the point source")


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
    Raises ``InvalidPointsError`` (shape, NaN/Inf, degenerate or wrongly scaled clouds: ``check_spread``, fewer than
    ``MIN_DISTINCT`` distinct positions), ``TooFewPointsError`` (P < ``min_points``).
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
    centre, qc64, qc, start = _centre(q, float(scale))                         # [3] m, [P', 3] model units (f64, f32)
    check_spread(qc64, centre, float(scale))
    idx = fps_order(qc, int(num_points), start=start)                          # [N], from the farthest point
    if len(idx) >= MIN_DISTINCT and _repeated(qc, idx[:MIN_DISTINCT]):        # FPS picks distinct points first
        raise InvalidPointsError(f"the {P} points hold fewer than {MIN_DISTINCT} distinct positions (repeated points); "
                                 "a pose needs the object's surface — check the crop or the point source")
    return PreparedPoints(model_points=np.ascontiguousarray(qc[idx]), centre_m=centre, scale=float(scale),
                          order=base[idx], cloud=qc)


@njit(cache=True)
def _centre(q, scale) -> tuple:
    """(centroid [3] of ``q`` [P, 3] metres, (q − centroid) / ``scale`` [P, 3] float64 and float32, the index of the
    float32 point farthest from the centroid)."""
    P = len(q)
    centre = np.zeros(3)
    for i in range(P):                                                          # row by row, as numpy's mean(0)
        for a in range(3):
            centre[a] += q[i, a]
    centre /= P
    qc64, qc = np.empty((P, 3)), np.empty((P, 3), np.float32)
    start, far = 0, np.float32(-1.0)
    for i in range(P):
        for a in range(3):
            qc64[i, a] = (q[i, a] - centre[a]) / scale
            qc[i, a] = qc64[i, a]
        r2 = qc[i, 0] * qc[i, 0] + qc[i, 1] * qc[i, 1] + qc[i, 2] * qc[i, 2]     # float32
        if r2 > far:
            start, far = i, r2
    return centre, qc64, qc, start


@njit(cache=True)
def _spread(x) -> tuple:
    """(RMS radius, scatter Σ x xᵀ [3, 3]) of the centred points ``x`` [P, 3] float64."""
    S = np.zeros((3, 3))
    for i in range(len(x)):
        for a in range(3):
            for b in range(3):
                S[a, b] += x[i, a] * x[i, b]
    return np.sqrt((S[0, 0] + S[1, 1] + S[2, 2]) / len(x)), S


@njit(cache=True)
def _repeated(qc, head) -> bool:
    """Whether two of the points ``qc[head]`` coincide (within 1e-9)."""
    for a in range(len(head)):
        for b in range(a + 1, len(head)):
            d = 0.0
            for k in range(3):
                d += (np.float64(qc[head[a], k]) - np.float64(qc[head[b], k])) ** 2
            if np.sqrt(d) <= 1e-9:
                return True
    return False
