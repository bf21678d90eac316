"""The up prior: hypothesis selection when the camera-frame "up" direction is known.

Objects that stand on a table or the floor in their usual rest pose have the category frame's up axis (+z for every
equipose category) along the support's normal, i.e. against gravity. Given that direction — the fitted support plane
(``up="plane"``), or an IMU's gravity reading turned into "up" — the pose has one free angle left, the azimuth about
it. The stage keeps the hypotheses whose up axis lies within ``UP_TOLERANCE_DEG`` of it, turns each exactly onto it,
refines the azimuth and translation by ICP against the predicted canonical shape (rotation kept about ``up``) and takes
the lowest residual. This removes the near-symmetries that a partial view leaves between "upright" and "lying" poses
(a laptop's base and screen, a sofa's seat and back); it cannot tell front from back (a 180° turn about ``up``), and
that is what ``ambiguous`` then reports.

Convention: ``points`` [N, 3] model input (model units, centred camera frame: no rotation, so camera-frame directions
apply unchanged); ``template`` [M, 3] the canonical shape in the category frame, model units; hypotheses ``R_cat``
[A, 3, 3], ``t_cat`` [A, 3] after calibration, ``scores`` [A] (lower better); ``up`` [3] unit, camera frame.
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import ConfigError
from equipose.runtime.hypotheses import (AMBIGUOUS_MARGIN, CONFIDENCE_MIN_ANGLE_DEG, FLIP_MIN_ANGLE_DEG, HALF_TURNS,
                                         Selection, symmetric_distance_deg)
from equipose.runtime.refine import icp_multi

__all__ = ["UP_TOLERANCE_DEG", "UP_AXIS", "check_up", "upright_icp", "select_upright", "resolve_plane_up",
           "resolve_support_plane", "per_object_up"]

UP_TOLERANCE_DEG = 40.0    # hypotheses whose up axis is this close to ``up`` are refined (≈ 7 of the 60)
UP_AXIS = 2                # the category frame's up axis (+z) for every equipose category
PLANE_MIN_HEIGHT_M = 0.012  # an object stands on a plane when enough of its points are higher than this:
PLANE_MIN_SHARE = 0.25      # this share (a bowl seen from above shows mostly its inside floor, just above the table)
COARSE_ITERS = 3          # ICP steps for every start
FINE_K, FINE_ITERS = 2, 8   # then this many best (+ the front/back partner of the best) go on for FINE_ITERS


def check_up(up, allow_plane: bool = True):
    """Validate an ``up`` argument: None, "plane" (where a depth frame gives a support plane) or a camera-frame
    direction [3] of any length > 0 (e.g. minus an accelerometer's gravity). Returns None, "plane" or a unit [3]."""
    if up is None:
        return None
    if isinstance(up, str):
        if up == "plane" and allow_plane:
            return "plane"
        where = "'plane' (the frame's support plane) or " if allow_plane else ""
        raise ConfigError(f"up must be {where}a camera-frame direction [3] (x right, y down, z forward), got {up!r}"
                          + ("" if allow_plane else "; 'plane' needs a depth frame: use predict / predict_batch"))
    try:
        u = np.asarray(up, np.float64)
    except (TypeError, ValueError):
        raise ConfigError(f"up must be a camera-frame direction [3], got {type(up).__name__}") from None
    if u.shape != (3,) or not np.all(np.isfinite(u)) or np.linalg.norm(u) < 1e-9:
        raise ConfigError(f"up must be a finite, non-zero camera-frame direction [3] (e.g. [0, -1, 0] for a level "
                          f"camera: OpenCV y points down), got {np.array2string(u, precision=3)}")
    return u / np.linalg.norm(u)


def upright_icp(points, template, R0, t0, up, iters: int = COARSE_ITERS + FINE_ITERS, bidirectional: bool = False,
                which=None) -> tuple:
    """ICP from several starts with the rotation's up axis held on ``up`` (each Kabsch step is turned back onto it).

    Convention: as the module's; ``R0`` [J, 3, 3], ``t0`` [J, 3] (``template`` [T, M, 3] with ``which`` [J]: see
    ``icp_multi``). Returns (R [J, 3, 3], t [J, 3], residual [J]) —
    mean squared nearest-neighbour distance observation → template (+ the reverse when ``bidirectional``).
    """
    return icp_multi(points, template, R0, t0, iters=iters, bidirectional=bidirectional, which=which,
                     hold=(UP_AXIS, up))


def select_upright(points, template, R_cat, t_cat, scores, up, *, symmetry: str = "none", top_k: int = 5,
                   tolerance_deg: float = UP_TOLERANCE_DEG, bidirectional: bool = False, starts=None) -> tuple:
    """Choose the pose given ``up``. Returns (``Selection``, R [3, 3], t [3] model units).

    The starts are the hypotheses within ``tolerance_deg`` of ``up`` (the nearest one when none is), or the given
    ``starts`` (hypothesis indices: keep an already selected azimuth, as the rest-facet stage does; the front/back
    partner then only informs ``ambiguous``). ``score`` is the
    ICP residual; ``confidence`` the relative margin to the best refined start > 30° away (modulo symmetry);
    ``ambiguous`` is set when the half turn about ``up`` (front/back) refines to within ``AMBIGUOUS_MARGIN`` of it.
    """
    up = check_up(up, allow_plane=False)
    s = np.asarray(scores, np.float64)
    ang = np.degrees(np.arccos(np.clip(R_cat[:, :, UP_AXIS] @ up, -1.0, 1.0)))   # [A] deg
    keep_azimuth = starts is not None                                           # the partner then only informs
    starts = np.nonzero(ang <= tolerance_deg)[0] if starts is None else np.atleast_1d(np.asarray(starts, int))
    if len(starts) == 0:
        starts = np.array([int(np.argmin(ang))])
    starts = starts[np.argsort(s[starts])]                                      # [J] best network score first
    x, y = np.asarray(points, np.float64), np.asarray(template, np.float64)
    R0 = R_cat[starts]
    t0 = x.mean(0) - R0 @ y.mean(0)                                             # [J, 3] centroids matched
    R, t, res = upright_icp(x, y, R0, t0, up, iters=COARSE_ITERS, bidirectional=bidirectional)
    # fine: the FINE_K best coarse poses and the half turn about up of the best (front/back), one batched ICP
    fine = np.argsort(res, kind="stable")[:FINE_K]                              # [F] indices into the starts
    Rf, tf, rf = upright_icp(x, y, np.concatenate([R[fine], (R[fine[0]] @ HALF_TURNS["z"])[None]]),
                             np.concatenate([t[fine], t[fine[0]][None]]), up, iters=FINE_ITERS,
                             bidirectional=bidirectional)
    R[fine], t[fine], res[fine] = Rf[:-1], tf[:-1], rf[:-1]
    starts = np.append(starts, starts[fine[0]])                                 # the partner keeps its start's index
    R, t, res = np.concatenate([R, Rf[-1:]]), np.concatenate([t, tf[-1:]]), np.append(res, rf[-1])
    refined = np.zeros(len(res), bool)
    refined[fine], refined[-1] = True, True
    res = np.where(refined, res, np.maximum(res, rf.max()))                    # coarse-only residuals rank behind
    order = np.argsort(res, kind="stable")
    b = int(np.argmin(res[:-1])) if keep_azimuth else int(order[0])           # res[-1]: the partner
    dist = symmetric_distance_deg(R[b], R, symmetry)                            # [J + 1] deg to the chosen
    far = [j for j in order if dist[j] > CONFIDENCE_MIN_ANGLE_DEG]
    confidence = 1.0 if not far else float((res[far[0]] - res[b]) / max(res[far[0]], 1e-12))
    flips = [j for j in order if refined[j] and dist[j] >= FLIP_MIN_ANGLE_DEG]
    flip_margin = float((res[flips[0]] - res[b]) / max(res[flips[0]], 1e-12)) if flips else float("nan")
    ambiguous = bool(flips) and flip_margin < AMBIGUOUS_MARGIN
    top = [{"index": int(starts[j]), "score": float(res[j]), "angle_deg": round(float(dist[j]), 2)}
           for j in order[:max(top_k, 1)]]
    sel = Selection(index=int(starts[b]), score=float(res[b]), confidence=float(np.clip(confidence, 0.0, 1.0)),
                    ambiguous=bool(ambiguous), runner_up=int(starts[far[0]]) if far else -1,
                    flip=int(starts[flips[0]]) if flips else -1,
                    runner_up_angle_deg=float(dist[far[0]]) if far else float("nan"), flip_margin=flip_margin,
                    top_k=top)
    return sel, R[b], t[b]


def resolve_support_plane(plane, points, min_height: float = PLANE_MIN_HEIGHT_M,
                          min_share: float = PLANE_MIN_SHARE) -> tuple | None:
    """The support plane an object stands on, as (unit normal [3], offset m): a camera-frame point x lies
    ``normal · x + offset`` metres above it. ``plane`` is (normal, offset) as ``find_support_plane`` returns it (the
    normal points to the camera side, i.e. up for a table seen from above). None: no plane, or the object's
    ``points`` [P, 3] (metres, camera frame) do not stand on it — fewer than ``min_share`` of them lie ``min_height``
    above it (the "plane" is the object's own face, or a wall behind it)."""
    if plane is None:
        return None
    n = np.asarray(plane[0], np.float64).reshape(3)
    heights = np.asarray(points, np.float64) @ n + float(plane[1])             # [P] m above the plane
    if np.mean(heights > min_height) < min_share:
        return None
    norm = float(np.linalg.norm(n))
    return n / norm, float(plane[1]) / norm


def resolve_plane_up(plane, points, min_height: float = PLANE_MIN_HEIGHT_M) -> np.ndarray | None:
    """Camera-frame up [3] from a support plane (``resolve_support_plane``'s normal), or None where the object does
    not stand on one."""
    support = resolve_support_plane(plane, points, min_height)
    return None if support is None else support[0]


def per_object_up(up, count: int) -> list:
    """``up`` for a batch of ``count`` point sets → a list of None or unit [3]: None, one direction [3] for all, or a
    list (or [count, 3] array) with one direction or None per object."""
    try:
        shared = up is None or isinstance(up, str) or np.asarray(up, np.float64).shape == (3,)
    except (TypeError, ValueError):                                             # a list holding None entries
        shared = False
    if shared:
        return [check_up(up, allow_plane=False)] * count
    if not hasattr(up, "__len__") or len(up) != count:
        n = len(up) if hasattr(up, "__len__") else "no"
        raise ConfigError(f"up has {n} entries for {count} point sets: give one direction [3] for all, or one "
                          "per point set")
    return [check_up(u, allow_plane=False) for u in up]
