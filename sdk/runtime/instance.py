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
Iterations: 50 by default (a start stops early once its pairs repeat). Measured on 10 poses of the whole YCB drill
(1 mm noise): with the v0.16 car-partial seeds, 30 left 2 poses 4.8–14° off and 50 ended all within 0.06–0.37°
(v0.15 seeds: 20 iterations 0.2–2.3°, 30 already 0.1–0.4°).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from equipose.core.errors import ConfigError
from equipose.core.geometry import farthest_point_order
from equipose.preprocess import check_points, prepare_points
from equipose.runtime.hypotheses import select_hypothesis
from equipose.runtime.refine import refine_hypotheses
from equipose.runtime.result import PoseResult

__all__ = ["InstanceModel", "build_instance_model", "finish_instance", "INSTANCE_ITERS"]

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


def finish_instance(est, inst: InstanceModel, outputs: dict, b: int, prep, *, prefer=None,
                    prefer_margin: float = 0.0) -> tuple:
    """Batch item ``b`` of a network run → (PoseResult of the CAD model, selection ms)."""
    t0 = time.perf_counter()
    R_all = outputs["hypothesis_rotations"][b]                                  # [60, 3, 3]
    t_all = outputs["hypothesis_translations"][b]                               # [60, 3] model units
    s_all = outputs["hypothesis_scores"][b]                                     # [60]
    # coarse: every hypothesis, a few ICP steps (an out-of-category object's network scores rank poorly); fine: the
    # k best of those to convergence
    R_all, t_all, s_all = refine_hypotheses(prep.model_points, inst.template, R_all, t_all, s_all, k=len(s_all),
                                            iters=COARSE_ITERS, bidirectional=False)
    R_all, t_all, s_all = refine_hypotheses(prep.model_points, inst.template, R_all, t_all, s_all, k=inst.k,
                                            iters=inst.iters, bidirectional=False)
    R_obj = np.einsum("aij,jk->aik", R_all, inst.A)                             # [60, 3, 3] CAD → camera
    t_obj = np.einsum("aij,j->ai", R_all, inst.b) + t_all                       # [60, 3] model units
    sel = select_hypothesis(R_obj, t_obj, s_all, symmetry="none", top_k=est.top_k, prefer=prefer,
                            prefer_margin=prefer_margin)
    U, _, Vt = np.linalg.svd(R_obj[sel.index])
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt                     # [3, 3]
    t_m = prep.to_metres(t_obj[sel.index])                                      # [3] metres, camera frame
    res = PoseResult(
        rotation=R, translation=t_m, score=sel.score, confidence=sel.confidence, ambiguous=sel.ambiguous,
        canonical_shape=inst.points_m @ R.T + t_m, canonical_shape_object=inst.points_m.copy(),
        hypothesis_index=sel.index, top_k=sel.top_k, symmetry="none", symmetry_axis=None, rotation_canonical=R.copy(),
        category=est.category, random_init=est.random_init)
    return res, (time.perf_counter() - t0) * 1e3
