"""What the camera would see of a posed canonical shape, and the view-aware residual that uses it.

A partial view is scored one way in ICP re-scoring (observed points → template): a pose that hides the object's
distinctive side behind the visible one fits as well as the right pose whenever the observed side fits somewhere on
the template (a sofa seen from the front fits its back turned 180°). The view-aware residual adds the other
direction for the template points the camera would see at that pose — hidden point removal (Katz, Tal and Basri,
SIGGRAPH 2007: spherical flip about the viewpoint, then the convex hull) on the posed template — so a pose is also
charged for visible template parts that the view does not contain.

Its effect on the partial models, alone and with the rotated copies' vote (``COPY_SUPPORT_WEIGHT``):
docs/results/models/README.md (v0.14).

Convention:
    Model units, the SDK's centred camera frame (``PreparedPoints.model_points``): the camera sits at
    ``viewpoint = −centre_m / scale``. Poses map the template into the observation, ``x = R y + t`` (column vectors).
    ``exponent`` sets the flip sphere's radius, ``10**exponent`` × the farthest point's distance: larger keeps more
    points (≈ 0.64 of a chair template at 2, 0.29 at 1).
"""
from __future__ import annotations

import numpy as np
from numba import njit
from scipy.spatial import ConvexHull
from scipy.spatial import QhullError

from equipose.core.errors import InvalidPointsError
from equipose.core.hull import hull_vertex_mask
from equipose.core.neighbours import NearestNeighbours
from equipose.core.parallel import run_parts, split_ranges, workers

__all__ = ["visible_mask", "view_residuals", "view_rescore", "DEFAULT_EXPONENT", "INCUMBENT_MARGIN", "VIEW_AMBIGUOUS_MARGIN",
           "COPY_SUPPORT_WEIGHT"]

DEFAULT_EXPONENT = 1.0
INCUMBENT_MARGIN = 0.2   # chosen on training views (chair-partial: 5° accuracy 0.598 → 0.612 at 0.2, 0.605 at 0)
VIEW_AMBIGUOUS_MARGIN = 0.5   # ``ambiguous`` below this flip margin of view-aware scores (they separate poses more
                              # than the one-way residual's 0.1, the copies' vote more again; chosen on 600 training
                              # views: sofa-partial flags 0.28 of results holding 0.57 of its flips, chair 0.07 / 0.73)
COPY_SUPPORT_WEIGHT = 0.8     # rotated copies: a pose's residual × (1 − this × the share of copies whose best
                              # hypothesis lies within ``merge_deg`` of it) (training views: sofa-partial flips
                              # 0.203 → 0.176, chair-partial 0.040 → 0.039)


def visible_mask(points: np.ndarray, viewpoint, exponent: float = DEFAULT_EXPONENT) -> np.ndarray:
    """[P] bool: the points of ``points`` [P, 3] a camera at ``viewpoint`` [3] would see (hidden point removal).

    Points at the viewpoint itself, or a degenerate (flat) set, count as visible (nothing is claimed hidden)."""
    P = np.asarray(points, np.float64)
    c = np.asarray(viewpoint, np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 4 or c.shape != (3,):
        raise InvalidPointsError(f"visible_mask needs points [P ≥ 4, 3] and a viewpoint [3], got {P.shape}, {c.shape}")
    if not np.all(np.isfinite(P)) or not np.all(np.isfinite(c)):
        raise InvalidPointsError("visible_mask: points or viewpoint contain NaN/Inf")
    flipped = np.empty((len(P) + 1, 3))                                        # [P + 1, 3] flip, then the camera
    if not _spherical_flip(np.ascontiguousarray(P), c, 10.0 ** float(exponent), flipped):
        return np.ones(len(P), bool)
    vertices, status = hull_vertex_mask(flipped, check=False)                   # [P + 1] compiled quickhull
    if status == "ok":
        return vertices[:len(P)]
    try:                                                                        # flat or nearly degenerate: qhull
        hull = ConvexHull(flipped)
    except QhullError:                                                          # coplanar / collinear
        return np.ones(len(P), bool)
    mask = np.zeros(len(P), bool)
    mask[hull.vertices[hull.vertices < len(P)]] = True
    return mask


@njit(cache=True, nogil=True)
def _spherical_flip(P, c, scale, out) -> bool:
    """``out`` [P + 1, 3] ← each point's ray d from the camera ``c``, pushed out to 2·radius − |d| along itself
    (radius = ``scale`` × the largest |d|), then the camera (the origin); False when a point sits on the camera."""
    n = len(P)
    r = np.empty(n)
    for i in range(n):
        d0, d1, d2 = P[i, 0] - c[0], P[i, 1] - c[1], P[i, 2] - c[2]
        r[i] = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if r[i] <= 0.0:
            return False
    radius = r.max() * scale
    for i in range(n):
        f = 2.0 * (radius - r[i])
        for k in range(3):
            d = P[i, k] - c[k]
            out[i, k] = d + f * d / r[i]
    out[n, 0], out[n, 1], out[n, 2] = 0.0, 0.0, 0.0
    return True


def view_residuals(observed: np.ndarray, template: np.ndarray, rotations: np.ndarray, translations: np.ndarray,
                   viewpoint, exponent: float = DEFAULT_EXPONENT) -> np.ndarray:
    """[J] view-aware residual of each pose: mean squared distance observed → posed template plus mean squared
    distance of the posed template's visible points → observed (model units²).

    ``observed`` [N, 3], ``template`` [M, 3] (learned frame), ``rotations`` [J, 3, 3], ``translations`` [J, 3],
    ``viewpoint`` [3] (the camera, same frame as ``observed``)."""
    x = np.asarray(observed, np.float64)
    Y = np.asarray(template, np.float64)
    R = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 3 or Y.ndim != 2 or Y.shape[1] != 3 or len(Y) < 4 \
            or R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (len(R), 3):
        raise InvalidPointsError(f"view_residuals needs observed [N, 3], template [M ≥ 4, 3], rotations [J, 3, 3] and "
                                 f"translations [J, 3], got {x.shape}, {Y.shape}, {R.shape}, {t.shape}")
    if not len(R):
        return np.empty(0)
    in_template = np.stack([(x - t[j]) @ R[j] for j in range(len(R))])        # [J, N, 3] observed, template frame
    parts = run_parts(_seen, [(Y, R[a:b], t[a:b], viewpoint, exponent)          # the poses in parts, side by side
                              for a, b in split_ranges(len(R), workers())])
    seen = [v for part in parts for v in part]                                  # [V_j, 3] each
    d_obs, _ = NearestNeighbours(Y).query(in_template)                          # [J, N] observed → template
    d_seen, _ = NearestNeighbours(x).query(np.concatenate(seen))                # [ΣV] visible template → observed
    ends = np.cumsum([len(p) for p in seen])[:-1]
    return np.array([float(np.mean(a ** 2) + np.mean(b ** 2))                   # [J], one query per direction
                     for a, b in zip(d_obs, np.split(d_seen, ends))])


def _seen(Y, R, t, viewpoint, exponent) -> list:
    """[V_j, 3] for each pose j of ``R`` [J, 3, 3], ``t`` [J, 3]: the points of the posed template ``Y`` [M, 3] (R y
    + t) that a camera at ``viewpoint`` sees."""
    posed = [Y @ R[j].T + t[j] for j in range(len(R))]                         # [M, 3] each
    return [p[visible_mask(p, viewpoint, exponent)] for p in posed]


def view_rescore(prep, template: np.ndarray, rotations: np.ndarray, translations: np.ndarray, scores: np.ndarray, *,
                 k: int, symmetry: str = "none", exponent: float = DEFAULT_EXPONENT, merge_deg: float = 15.0,
                 margin: float = INCUMBENT_MARGIN, copy_poses=None, support_weight: float = COPY_SUPPORT_WEIGHT
                 ) -> np.ndarray:
    """New scores [A] after view-aware re-scoring of the ``k`` best (ICP-refined) hypotheses of one object.

    ``prep``: its ``PreparedPoints`` (observed ``model_points``; the camera at ``−centre_m / scale``); ``template``
    [M, 3] learned frame; ``rotations`` [A, 3, 3], ``translations`` [A, 3], ``scores`` [A] (lower better), all in the
    learned frame and model units. A hypothesis within ``merge_deg`` (modulo ``symmetry``) of a better-ranked one
    stays right behind it (the best of a group, e.g. the copies' consensus, keeps its place; only distinct poses
    compete); the groups' heads are ranked by ``view_residuals``, the first head's (the best of the old ranking)
    scaled by ``1 − margin``, so another pose replaces it only with a residual lower by more than that fraction; the
    other hypotheses rank behind them all in their old order. ``copy_poses`` [K, 3, 3] (the rotated copies' best
    rotations, same frame): each head's residual is also scaled by ``1 − support_weight × support``, support = the
    share of copies within ``merge_deg`` of it, so a pose most copies found needs a clearer residual to be replaced.
    """
    from equipose.runtime.hypotheses import symmetric_distance_deg
    R = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    s = np.asarray(scores, np.float64)
    order = np.argsort(s, kind="stable")[: max(1, int(k))]                     # [k] best first
    heads, member, near_head = [], {}, {}                  # near_head[h]: [k] bool, the ranked poses within merge_deg
    for n, i in enumerate(order):
        near = [h for h in heads if near_head[h][n]]
        if near:
            member[int(i)] = near[0]
        else:
            heads.append(int(i))
            near_head[int(i)] = symmetric_distance_deg(R[i], R[order], symmetry) <= merge_deg   # [k]
    v = view_residuals(prep.model_points, template, R[heads], t[heads], prep.camera, exponent)   # [H]
    v[0] *= 1.0 - float(margin)                                                 # the incumbent's benefit of doubt
    if copy_poses is not None:                                                  # the copies' vote
        C = np.asarray(copy_poses, np.float64)                                  # [K, 3, 3]
        if C.ndim != 3 or C.shape[1:] != (3, 3) or not len(C):
            raise InvalidPointsError(f"view_rescore: copy_poses must be [K ≥ 1, 3, 3], got {C.shape}")
        support = np.array([np.mean(symmetric_distance_deg(R[h], C, symmetry) <= merge_deg) for h in heads])  # [H]
        v *= 1.0 - float(support_weight) * support
    out = np.empty_like(s)
    out[heads] = v
    for i, h in member.items():                                                 # right behind its group's head
        out[i] = np.nextafter(out[h], np.inf)
    top = max(out[heads].max(), max((out[i] for i in member), default=-np.inf))
    others = np.ones(len(s), bool)
    others[order] = False
    rest = np.flatnonzero(others)                                              # ascending, as setdiff1d gave
    if len(rest):
        out[rest] = top + 1e-9 + (s[rest] - s[rest].min())
    return out
