"""Instance-level mode: each pose checked against its crop (``fit_shares``) and the depth frame
(``see_through_share``); with a box prompt, where the chosen cluster's pose claims space the camera sees through, the
box's other depth clusters are posed too (``PoseEstimator`` reports both shares in every instance result's extras).

A box crop keeps one depth cluster, chosen by box evidence (``equipose.preprocess.surfaces.box_object_cluster``: the
cluster the box is centred on, that fills it, that does not run on past its sides). Where the object stands behind
something that sits in the middle of its box (a cracker box behind a mustard bottle), that evidence picks the thing in
front. In instance-level mode the object's own model can tell: posed on the thing in front, the model stands where the
depth frame sees farther, through it (``see_through_share``). Where that share exceeds ``SEE_THROUGH_MAX`` and the crop
found two or more depth clusters, the box is cropped again beyond the chosen cluster and before it
(``other_cluster_gates``), each crop is posed, and the pose with the lowest share wins when it is below the bound.
A fit share of the crop's points is no test here: a part of any surface fits a part of the model (the cracker box's
pose on the bottle fits 0.74 of the bottle's points, the same share as its pose on its own face), and neither is a
count of explained points (the bottle posed flush on the box face behind it explains more points than on itself).

Convention: metres, camera frame; poses map the CAD frame into the camera frame (``p = R q + t``); ``K`` [3, 3]
pixels of the depth frame.
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import InvalidPointsError

__all__ = ["GAP_M", "NEAR_M", "SEE_THROUGH_M", "SEE_THROUGH_MAX", "FRONT_M", "other_cluster_gates", "fit_shares",
           "see_through_share", "choose_cluster"]

GAP_M = 0.01            # a re-crop's depth gate starts this far beyond (ends this far before) the chosen cluster
NEAR_M = 0.005          # a crop point within this of a posed model point fits the pose (reported)
SEE_THROUGH_M = 0.02    # a visible model point whose pixel sees farther than this behind it is seen through
SEE_THROUGH_MAX = 0.35  # poses seen through on a larger share of their visible points are not the object's
FRONT_M = 0.005         # model points within this of their pixel's nearest model point are on its visible side


def other_cluster_gates(points: np.ndarray, min_depth: float = 0.1, max_depth: float = 10.0) -> list:
    """The depth gates of the re-crops: crop options {"min_depth": …} beyond the chosen cluster's deepest point and
    {"max_depth": …} before its nearest one, each only where it leaves a range within [``min_depth``, ``max_depth``].

    Convention: ``points`` [P, 3] metres, the chosen crop (camera frame; depth = z). Returns a list of dicts.
    """
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not len(p):
        raise InvalidPointsError(f"other_cluster_gates needs the chosen crop's points [P ≥ 1, 3] metres, got {p.shape}")
    z = p[:, 2]                                                                 # [P] metres
    gates = []
    beyond, before = float(z.max()) + GAP_M, float(z.min()) - GAP_M
    if beyond < max_depth:
        gates.append({"min_depth": beyond, "max_depth": float(max_depth)})
    if before > min_depth:
        gates.append({"min_depth": float(min_depth), "max_depth": before})
    return gates


def fit_shares(rotations, translations, model_points: np.ndarray, crops: list, tree=None) -> np.ndarray:
    """[C] float: for each candidate c, the share of its crop's points within ``NEAR_M`` of the model posed by it.

    Convention: ``rotations`` [C, 3, 3], ``translations`` [C, 3] metres (camera ← CAD); ``model_points`` [M, 3]
    metres, CAD frame; ``crops``: C arrays [P_c, 3] metres, camera frame. Each crop is taken into the CAD frame and
    searched in ``tree`` (a ``scipy.spatial.cKDTree`` of ``model_points``, built here when not given).
    """
    from scipy.spatial import cKDTree

    R = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    Q = np.asarray(model_points, np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (len(R), 3) or Q.ndim != 2 or Q.shape[1] != 3 \
            or len(crops) != len(R):
        raise InvalidPointsError(f"fit_shares needs R [C, 3, 3], t [C, 3], model [M, 3] and C crops; got {R.shape}, "
                                 f"{t.shape}, {Q.shape}, {len(crops)} crops")
    tree = cKDTree(Q) if tree is None else tree
    shares = np.zeros(len(R))
    for c, X in enumerate(crops):
        X = np.asarray(X, np.float64)                                          # [P, 3] m, camera frame
        if X.ndim != 2 or X.shape[1] != 3 or not len(X):
            raise InvalidPointsError(f"fit_shares: crop {c} must be [P ≥ 1, 3] metres, got {X.shape}")
        d, _ = tree.query((X - t[c]) @ R[c], distance_upper_bound=NEAR_M)     # [P] in the CAD frame, inf beyond
        shares[c] = np.count_nonzero(d < NEAR_M) / len(X)
    return shares


def see_through_share(R, t, model_points: np.ndarray, depth_m: np.ndarray, K) -> float:
    """Share of the posed model's visible points whose pixel's depth lies more than ``SEE_THROUGH_M`` behind them:
    the camera sees through where the pose puts the object (0 where no visible point has valid depth).

    Convention: ``R`` [3, 3], ``t`` [3] metres (camera ← CAD); ``model_points`` [M, 3] metres, CAD frame;
    ``depth_m`` [H, W] metres (0 = invalid); ``K`` [3, 3]. Visible: within ``FRONT_M`` of the nearest model point in
    its pixel (a z-buffer of the points themselves).
    """
    X = np.asarray(model_points, np.float64) @ np.asarray(R, np.float64).T + np.asarray(t, np.float64)   # [M, 3]
    d = np.asarray(depth_m)
    if d.ndim != 2:
        raise InvalidPointsError(f"see_through_share needs a [H, W] depth frame in metres, got {d.shape}")
    H, W = d.shape
    z = X[:, 2]                                                                 # [M]
    ahead = z > 1e-6
    X, z = X[ahead], z[ahead]
    u = np.rint(X[:, 0] / z * K[0][0] + K[0][2]).astype(np.int64)               # [M'] pixel columns
    v = np.rint(X[:, 1] / z * K[1][1] + K[1][2]).astype(np.int64)               # [M'] pixel rows
    inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
    u, v, z = u[inside], v[inside], z[inside]
    if not len(z):
        return 0.0
    u0, v0 = int(u.min()), int(v.min())
    w = int(u.max()) - u0 + 1
    pix = (v - v0) * w + (u - u0)                                               # [M''] pixel in the model's window
    nearest = np.full((int(v.max()) - v0 + 1) * w, np.inf)
    np.minimum.at(nearest, pix, z)                                              # z-buffer of the model points
    visible = z <= nearest[pix] + FRONT_M                                       # [M''] bool
    seen = d[v[visible], u[visible]]                                            # [V] observed depth, metres
    valid = seen > 0
    if not valid.any():
        return 0.0
    return float(np.mean(seen[valid] > z[visible][valid] + SEE_THROUGH_M))


def choose_cluster(see_through) -> int:
    """Index of the kept candidate: 0 (the box-evidence crop) unless its see-through share exceeds
    ``SEE_THROUGH_MAX``; then the candidate with the lowest share where that is within the bound, else 0."""
    s = np.asarray(see_through, np.float64)
    if len(s) < 2 or s[0] <= SEE_THROUGH_MAX:
        return 0
    j = 1 + int(np.argmin(s[1:]))
    return j if s[j] <= SEE_THROUGH_MAX else 0
