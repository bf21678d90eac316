"""ICP refinement and re-scoring of the network's best hypotheses against its own predicted canonical shape.

Convention:
    Poses map a template into an observation, x ≈ R @ y + t (column vectors), in one set of units (the SDK uses model
    units: the observation is ``PreparedPoints.model_points``, the template the ``canonical_shape`` output in the
    network's learned frame, i.e. the frame its raw hypotheses refer to, before calibration). Residual: mean squared
    nearest-neighbour distance observation → template (plus template → observation when ``bidirectional``, for
    complete inputs; a partial view covers only part of the template). The ICP itself is ``equipose.core.icp``
    (all starts in one loop). torch-free.

Which models re-score how many hypotheses, with how many iterations, is chosen per file and measured in
docs/results/models/README.md.
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import ConfigError, InvalidPointsError
from equipose.core.icp import icp_multi, icp_point_to_plane, kabsch

__all__ = ["kabsch", "icp_multi", "refine_hypotheses", "rank_refined"]


def refine_hypotheses(points: np.ndarray, template: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                      scores: np.ndarray, k: int = 5, iters: int = 10, bidirectional: bool = False,
                      normals: np.ndarray | None = None, tol: float = 1e-7) -> tuple:
    """ICP-refine the ``k`` best-scored hypotheses and re-score them by their ICP residual.

    With the template's ``normals`` [M, 3] the ICP is point-to-plane (``icp_point_to_plane``, stopping at steps below
    ``tol``; one-way only), else point-to-point (``icp_multi``). Both report the point-to-point residual.

    Convention: ``points`` [N, 3] observation, ``template`` [M, 3] the predicted canonical shape (learned frame),
    ``rotations`` [A, 3, 3], ``translations`` [A, 3], ``scores`` [A] (lower better) — all in model units.
    Returns new (rotations, translations, scores) of the same shapes: the k best are replaced by their refined poses
    with the residual as score; the others keep their order but are ranked behind every refined one (their scores
    are shifted above the largest residual), so selection picks among the refined ones and the confidence still
    compares against distinct alternatives.
    """
    R = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    s = np.asarray(scores, np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (len(R), 3) or s.shape != (len(R),):
        raise InvalidPointsError(f"hypotheses must be [A, 3, 3], [A, 3], [A]; got {R.shape}, {t.shape}, {s.shape}")
    if normals is not None and bidirectional:
        raise ConfigError("point-to-plane refinement (normals given) fits observation → template only: pass "
                          "bidirectional=False")
    k = int(min(max(k, 1), len(R)))
    top = np.argsort(s)[:k]                                                    # [k]
    if normals is None:
        Rk, tk, res = icp_multi(points, template, R[top], t[top], iters=iters, bidirectional=bidirectional)
    else:
        Rk, tk, res = icp_point_to_plane(points, template, normals, R[top], t[top], iters=iters, tol=tol)
    R_out, t_out = R.copy(), t.copy()
    R_out[top], t_out[top] = Rk, tk
    return R_out, t_out, rank_refined(s, top, res)


def rank_refined(scores: np.ndarray, top: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    """New scores [A]: the refined hypotheses ``top`` [k] score their ICP ``residuals`` [k]; the others keep their
    order but rank behind every refined one (shifted above the largest residual)."""
    s = np.asarray(scores, np.float64)
    out = np.empty_like(s)
    out[top] = residuals
    others = np.ones(len(s), bool)
    others[top] = False
    rest = np.flatnonzero(others)                                              # ascending, as setdiff1d gave
    if len(rest):
        out[rest] = residuals.max() + 1e-9 + (s[rest] - s[rest].min())
    return out
