"""Instance-level mode: a known object model (CAD points) takes the role of the predicted canonical shape.

Convention:
    ``model_points`` [M, 3] metres in the object's own (CAD) frame. Poses returned map that frame into the camera frame,
    ``p_cam = R · q + t`` (metres), so ``PoseResult.rotation`` / ``translation`` are the CAD model's pose; no category
    calibration and no symmetry are applied.

How: the network is run once on the model points (centred, scaled to model units) to express them in its learned
frame, ``y = A · q / s + b`` (A = R_cᵀ, b = −R_cᵀ (c_q / s + t_c) from its best hypothesis (R_c, t_c)). For an
observation, the network's hypotheses (R_i, t_i) map learned frame → observation, ``x ≈ R_i y + t_i``; all 60 get
``COARSE_ITERS`` ICP steps against ``y``, the ``k`` best of those are refined to convergence and re-ranked by residual
(observation → model), and the winner is composed back:
``R = R_i A``, ``t = s (R_i b + t_i) + c``. An equivariant network gives the same composed seeds whatever the CAD
frame is, so a category model is a seed generator for any object; ICP on the true geometry gives the precision.
Iterations: 50 by default (a start stops early once its pairs repeat; the choice is measured in
docs/results/models/README.md, instance-level mode).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from equipose.core.errors import ConfigError
from equipose.core.geometry import farthest_point_order
from equipose.preprocess import check_points, prepare_points

__all__ = ["InstanceModel", "build_instance_model", "INSTANCE_ITERS"]

TEMPLATE_POINTS = 1024          # model points kept (FPS) for ICP
COARSE_ITERS = 3                # ICP steps for every hypothesis before the k best are refined
INSTANCE_ITERS = 50             # ICP iterations of the k best (default of PoseEstimator(instance_iters=...))


@dataclass
class InstanceModel:
    """A known object in the network's learned frame.

    Attributes: ``points_m`` [M, 3] metres, CAD frame; ``template`` [M', 3] model units, learned frame (FPS subset);
    ``A`` [3, 3], ``b`` [3]: CAD (metres / scale) → learned frame; ``k`` hypotheses refined per observation;
    ``iters`` ICP iterations.
    """
    points_m: np.ndarray
    template: np.ndarray
    A: np.ndarray
    b: np.ndarray
    k: int
    iters: int


def build_instance_model(est, model_points, *, k: int = 10, iters: int = INSTANCE_ITERS) -> InstanceModel:
    """Express ``model_points`` [M, 3] metres (CAD frame) in ``est``'s learned frame (one network run)."""
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= 60 or isinstance(iters, bool) \
            or not isinstance(iters, int) or iters < 1:
        raise ConfigError(f"instance_k must be an int in 1..60 and instance_iters an int ≥ 1, got {k!r}, {iters!r}")
    q = check_points(model_points, "model_points")                             # [M, 3] m, CAD frame
    prep = prepare_points(q, est.num_points, est.scale)                        # complete cloud → model units
    out = (est.runner or est.run_model)(prep.model_points[None])
    best = int(np.argmin(out["hypothesis_scores"][0]))
    R_c = np.asarray(out["hypothesis_rotations"][0, best], np.float64)         # [3, 3] learned → CAD (model units)
    t_c = np.asarray(out["hypothesis_translations"][0, best], np.float64)      # [3]
    U, _, Vt = np.linalg.svd(R_c)
    R_c = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    A, b = R_c.T, -R_c.T @ (prep.centre_m / est.scale + t_c)
    sub = q[farthest_point_order(q.astype(np.float32), min(TEMPLATE_POINTS, len(q)))]  # [M', 3] m
    return InstanceModel(points_m=q, template=sub / est.scale @ A.T + b, A=A, b=b, k=k, iters=iters)
