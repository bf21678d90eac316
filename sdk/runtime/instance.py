"""Instance-level mode: a known object model (CAD points) takes the role of the predicted canonical shape.

Convention:
    ``model_points`` [M, 3] metres in the object's own (CAD) frame. Poses returned map that frame into the camera frame,
    ``p_cam = R · q + t`` (metres), so ``PoseResult.rotation`` / ``translation`` are the CAD model's pose; no category
    calibration and no symmetry are applied.

How: the network is run once on the model points (centred, scaled to model units) to express them in its learned frame,
``y = A · q / s + b`` (A = R_cᵀ, b = −R_cᵀ (c_q / s + t_c) from its best hypothesis (R_c, t_c)). For an observation, the
network's hypotheses (R_i, t_i) map learned frame → observation, ``x ≈ R_i y + t_i``; coarse to fine, all 60 get
``COARSE_ITERS`` point-to-point ICP steps (``COARSE_POINTS`` of the observation against the first
``SUB_TEMPLATE_POINTS`` of the FPS-ordered template: a dense product), the ``k`` best of those converge point-to-plane
(``equipose.core.icp.icp_point_to_plane``, template normals from ``equipose.core.normals``) against that part of the
template, the ``FINE_K`` best of those again against the whole template and then get ``POLISH_ITERS`` point-to-point
steps, re-ranked by residual (observation → model), and the winner is composed back: ``R = R_i A``, ``t = s (R_i b +
t_i) + c``. An equivariant network gives the same composed seeds whatever the CAD frame is, so a category model is a
seed generator for any object; ICP on the true geometry gives the precision. Point-to-point ICP alone creeps along flat
parts and stalls a few degrees off (measured in docs/benchmarks.md, v0.31).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from equipose.core.errors import ConfigError
from equipose.core.geometry import farthest_point_order
from equipose.core.normals import point_normals
from equipose.preprocess import check_points, prepare_points

__all__ = ["InstanceModel", "build_instance_model", "INSTANCE_ITERS", "COARSE_ITERS", "COARSE_POINTS",
           "SUB_TEMPLATE_POINTS", "FINE_K", "CONVERGED_STEP", "POLISH_ITERS", "TURN_CONVERGE_ITERS", "TRIM_M",
           "TRIM_GATE", "turned_fits", "undecided_turn", "better_turn", "trimmed_search"]

TEMPLATE_POINTS = 1024          # model points kept (FPS) for ICP
VERIFY_POINTS = 8192            # model points kept (FPS) to check a pose against a crop (instance_clusters)
COARSE_ITERS = 3                # ICP steps for every hypothesis before the k best are refined ...
COARSE_POINTS = 64              # ... on this many observed points (FPS prefix of the model input)
SUB_TEMPLATE_POINTS = 256       # model points (FPS prefix) of the coarse steps and of the k best's convergence
FINE_K = 3                      # hypotheses converged again on the whole template
INSTANCE_ITERS = 15             # point-to-plane iterations to convergence (PoseEstimator(instance_iters=...))
CONVERGED_STEP = 1e-5           # ... a start stops once a step moves less (radians, model units)
POLISH_ITERS = 10               # point-to-point iterations of the FINE_K best after their convergence
TURN_CONVERGE_ITERS = 50        # point-to-point iterations that converge a turned start which fits better
TURN_ANGLES_DEG = (60.0, 120.0, 180.0, 240.0, 300.0)   # turns of the chosen pose tried about each principal axis
TURN_ITERS = 6                  # ICP steps of each turned start
TURN_TEMPLATE_POINTS = 256      # template points of the turn test (a dense product instead of a k-d tree)
TURN_MIN_DEG = 30.0             # a turned start that ends closer than this to the chosen pose slid back to it
TRIM_M = 0.01                   # trimmed search: crop points farther than this (metres) from the model do not pull
TRIM_GATE = 0.2                 # ... run where the winner's truncated residual exceeds this × TRIM_M²
TRIM_POINTS = 64                # ... every coarse start, on this many observed points (FPS prefix) ...
TRIM_ITERS = 6                  # ... for this many point-to-plane steps against the sub-template ...
TRIM_K = 10                     # ... the best this many on all points against the whole template ...
TRIM_SORT_ITERS = 8             # ... for this many steps, and the best of those ...
TRIM_FINE_ITERS = 15            # ... for this many more


@dataclass
class InstanceModel:
    """A known object in the network's learned frame.

    Attributes: ``points_m`` [M', 3] metres, CAD frame (an FPS subset of the model points, FPS-ordered); ``template``
    [M', 3] the same points in model units, learned frame; ``normals`` [M', 3] the template's unit normals;
    ``A`` [3, 3], ``b`` [3]: CAD (metres / scale) → learned frame; ``k`` hypotheses refined per observation;
    ``iters`` point-to-plane iterations to convergence; ``verify_m`` [M'', 3] metres, CAD frame: the model points a
    pose is checked against (all of them, or ``VERIFY_POINTS`` by FPS; ``equipose.runtime.instance_clusters``) and
    ``verify_tree`` their ``scipy.spatial.cKDTree``.
    """
    points_m: np.ndarray
    template: np.ndarray
    normals: np.ndarray
    A: np.ndarray
    b: np.ndarray
    k: int
    iters: int
    verify_m: np.ndarray | None = None
    verify_tree: object = None


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
    template = sub / est.scale @ A.T + b                                        # [M', 3] model units, learned frame
    dense = q if len(q) <= VERIFY_POINTS else q[farthest_point_order(q.astype(np.float32), VERIFY_POINTS)]
    from scipy.spatial import cKDTree
    dense = np.asarray(dense, np.float64)
    return InstanceModel(points_m=sub, template=template, normals=point_normals(template), A=A, b=b, k=k, iters=iters,
                         verify_m=dense, verify_tree=cKDTree(dense))


def turned_fits(points: np.ndarray, template: np.ndarray, R: np.ndarray, t: np.ndarray, normals=None) -> tuple:
    """The chosen pose's turns about the template's principal axes, each after ``TURN_ITERS`` ICP steps.

    Convention: ``points`` [N, 3] the observation, ``template`` [M, 3] FPS-ordered, both model units; (``R`` [3, 3],
    ``t`` [3]) the chosen pose (template → observation). Residuals (mean squared observed → template distance) are
    taken on the template's first ``TURN_TEMPLATE_POINTS`` points. Each turn of ``TURN_ANGLES_DEG`` about each
    principal axis through the template's centroid is one ICP start: point-to-plane when the template's ``normals``
    [M, 3] are given (it reaches the turned basin in fewer steps), else point-to-point. Returns (the pose's
    residual, the turns' poses [T, 3, 3] and [T, 3], their residuals [T], [T] bool: ended more than
    ``TURN_MIN_DEG`` from the pose, i.e. did not slide back to it).
    """
    from scipy.spatial.transform import Rotation

    from equipose.core.icp import icp_multi, icp_point_to_plane
    template = template[:TURN_TEMPLATE_POINTS]                                  # FPS prefix: an even subsample
    _, _, base = icp_multi(points, template, R[None], t[None], iters=0)        # the pose's residual on it
    c = template.mean(0)                                                        # [3]
    _, _, axes = np.linalg.svd(template - c, full_matrices=False)               # [3, 3] rows: principal axes
    turns = Rotation.from_rotvec(np.concatenate([np.radians(TURN_ANGLES_DEG)[:, None] * a[None] for a in axes]))
    Rs = R @ turns.as_matrix()                                                  # [T, 3, 3] turned about c
    ts = t + R @ c - np.einsum("kij,j->ki", Rs, c)                              # [T, 3] c stays where it was
    if normals is None:
        Rf, tf, res = icp_multi(points, template, Rs, ts, iters=TURN_ITERS)
    else:                                                                       # point-to-plane reaches the basin
        Rf, tf, res = icp_point_to_plane(points, template, normals[:TURN_TEMPLATE_POINTS], Rs, ts, iters=TURN_ITERS,
                                         tol=CONVERGED_STEP)
    cos = (np.einsum("kij,ij->k", Rf, R) - 1.0) / 2.0                           # [T] cos of the angle to the pose
    return float(base[0]), Rf, tf, res, cos < np.cos(np.radians(TURN_MIN_DEG))


def trimmed_search(points: np.ndarray, template: np.ndarray, normals: np.ndarray, R0: np.ndarray, t0: np.ndarray,
                   max_dist: float) -> tuple:
    """The pose that fits the most of the view within ``max_dist``: every start (R0 [J, 3, 3], t0 [J, 3]) gets
    ``TRIM_ITERS`` trimmed point-to-plane steps (``equipose.core.icp.icp_point_to_plane(max_dist=...)``) on the first
    ``TRIM_POINTS`` observed points against the first ``SUB_TEMPLATE_POINTS`` template points, the ``TRIM_K`` best
    ``TRIM_SORT_ITERS`` more on all of them against the whole template, and the best of those ``TRIM_FINE_ITERS``
    more. Convention: model units, ``points`` [N, 3] and ``template`` [M, 3]
    FPS-ordered, unit template ``normals`` [M, 3]. Returns (R [3, 3], t [3], its truncated residual on all points)."""
    from equipose.core.icp import icp_point_to_plane
    sub = min(SUB_TEMPLATE_POINTS, len(template))
    R, t, r = icp_point_to_plane(points[:TRIM_POINTS], template[:sub], normals[:sub], R0, t0, iters=TRIM_ITERS,
                                 tol=CONVERGED_STEP, max_dist=max_dist)
    best = np.argsort(r)[:TRIM_K]                                               # [K] lowest truncated residuals
    R, t, r = icp_point_to_plane(points, template, normals, R[best], t[best], iters=TRIM_SORT_ITERS,
                                 tol=CONVERGED_STEP, max_dist=max_dist)
    j = int(np.argmin(r))
    R, t, r = icp_point_to_plane(points, template, normals, R[j][None], t[j][None], iters=TRIM_FINE_ITERS,
                                 tol=CONVERGED_STEP, max_dist=max_dist)
    return R[0], t[0], float(r[0])


def undecided_turn(points: np.ndarray, template: np.ndarray, R: np.ndarray, t: np.ndarray, margin: float,
                   fits: tuple | None = None) -> bool:
    """Whether a turn of the chosen pose about one of the template's principal axes fits the view about as well
    (``turned_fits``, or its result ``fits`` for this pose): one that did not slide back ends within ``margin`` of
    the pose's residual, (r − residual) / r < margin — the view cannot tell the turn from the pose (a symmetry axis,
    or the side that would tell is hidden)."""
    residual, _, _, res, away = fits if fits is not None else turned_fits(points, template, R, t)
    rel = (res - residual) / np.maximum(res, 1e-12)                             # [T]
    return bool(np.any((rel < margin) & away))


def better_turn(points: np.ndarray, template: np.ndarray, residual: float, fits: tuple, iters: int):
    """A turn that fits the view better than the chosen pose: every turned start of ``fits`` (``turned_fits``)
    whose residual is already below the pose's is ICP-converged (``iters``) on the whole ``template``; the best as
    (R [3, 3], t [3], residual) when its converged residual beats ``residual`` (the pose's on the whole template),
    else None. The hypotheses' starts can all miss the basin of the true pose (a seed network of another
    category)."""
    from equipose.core.icp import icp_multi
    base, Rf, tf, res, away = fits
    better = away & (res < base)                                                # [T]
    if not better.any():
        return None
    Rj, tj, rj = icp_multi(points, template, Rf[better], tf[better], iters=iters)
    j = int(np.argmin(rj))
    return (Rj[j], tj[j], float(rj[j])) if rj[j] < residual else None
