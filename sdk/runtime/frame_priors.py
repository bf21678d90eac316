"""Frame priors of complete-shape models (metadata ``frame_priors``): the pose turned onto the object's own geometry.

Furniture and vehicles are built around a mirror plane (left/right) and stand on a footprint whose outline is square
with the object (a sofa's back, a car's sides). A category frame that has its mirror plane normal to one axis and its
footprint's minimum-area rectangle along x and y is where such a model's calibrated frame points on average, but the
self-supervised frame of one instance can sit a few degrees off (the learned frame varies from shape to shape). The
steps, in the order the metadata lists them, turn the pose onto the cloud's own geometry within a bound:

- ``"mirror"``: the cloud's mirror plane nearest to the pose's ``mirror_axis`` (``mirror_plane``, a reflective ICP);
  the pose turns by the smallest rotation taking that axis onto the plane's normal;
- ``"footprint"``: the minimum-area rectangle of the cloud projected along the pose's +z (opencv ``minAreaRect``); the
  pose turns about +z onto the rectangle's nearest side;
- ``"rest"``: the pose's +z turns onto the up of the hull face the cloud rests on (``equipose.runtime.rest_facet``,
  within ``max_deg``) by the smallest rotation (models with metadata ``rest_facet`` run the fuller rest-facet stage
  before these steps; this step serves where no network outputs are at hand, e.g. a teacher's distillation targets).

A step whose answer lies farther than ``max_deg`` from the pose leaves it as it is (an asymmetric instance, an L-shaped
sofa). Label-free at run time; which steps (and mirror axis) a model uses is chosen once, on training clouds, by
``python -m equipose.export.frame_priors``. For complete clouds: a single view holds neither the mirror image of what
it shows nor the whole footprint (measured: worse on every partial model).

Convention: ``points`` [P, 3] the object's cloud, centred, any units, camera frame; ``rotation`` [3, 3] category →
camera (column vectors); angles in degrees.
"""
from __future__ import annotations

import cv2
import numpy as np
from numba import njit

from equipose.core.errors import ConfigError, InvalidPointsError
from equipose.core.geometry import axis_angle_deg, nearest_rotation, rotation_between
from equipose.core.eigen import top_eigenvector
from equipose.core.nearest import build_index, make_scratch, nearest_brute, nearest_tree
from equipose.core.parallel import run_parts, split_ranges, workers
from equipose.core.metadata import FRAME_PRIOR_STEPS
from equipose.runtime.rest_facet import rest_facet_up

__all__ = ["FRAME_PRIOR_STEPS", "MAX_DEG", "MIRROR_ITERS", "MIRROR_STEP", "MIRROR_FINE",
           "parse_steps", "mirror_plane", "footprint_yaw", "apply_frame_priors"]

MAX_DEG = 20.0                  # default bound on how far a step may turn the pose
MIRROR_ITERS = 8
MIRROR_STEP = 2.0               # each update after the first goes this many times its own step (over-relaxation)
MIRROR_FINE = 2                 # with ``coarse`` > 1: the last iterations, on the whole cloud
_MIRROR_TRIM = 0.8              # pairs kept per iteration (the closest): asymmetric parts drop out
_AXES = {"x": 0, "y": 1, "z": 2}


def parse_steps(text: str, max_deg: float = MAX_DEG) -> dict | None:
    """"footprint,mirror:y" → the metadata dict ({"steps", "mirror_axis", "max_deg"}); "none" or "" → None.
    Raises ``ConfigError`` for an unknown step or a mirror step without its axis."""
    if text in ("none", ""):
        return None
    steps, axis = [], None
    for part in text.split(","):
        name, _, ax = part.strip().partition(":")
        if name not in FRAME_PRIOR_STEPS or (name == "mirror") != bool(ax) or (ax and ax not in _AXES):
            raise ConfigError(f"frame-prior steps: {part!r} is not 'rest', 'footprint' or 'mirror:<x|y|z>' "
                              "(e.g. 'footprint,mirror:x')")
        steps.append(name)
        axis = ax or axis
    return {"steps": steps, "mirror_axis": axis, "max_deg": float(max_deg)}


def _check(points, rotation) -> tuple:
    P = np.asarray(points, np.float64)
    R = np.asarray(rotation, np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 8 or not np.all(np.isfinite(P)):
        raise InvalidPointsError(f"frame priors need a finite [P ≥ 8, 3] cloud, got {np.shape(points)}")
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise InvalidPointsError(f"frame priors need a finite [3, 3] rotation, got {np.shape(rotation)}")
    return P, R


@njit(cache=True, nogil=True)
def _reflect_and_pair(index, n, d, lo, hi, pair, d2) -> None:
    """For the cloud points ``lo`` … ``hi`` of the ``index`` (its set 0): the nearest cloud point to each one's
    reflection in the plane n·x = d (``pair``, warm-started from its previous value) and the squared distance
    (``d2``). Parts over disjoint ranges may run side by side."""
    P, soa, centre, tpoints, ids, nodes, split = index
    X = P[0]                                                                   # [P, 3]
    stack, bound, dist, bits = make_scratch(len(X))
    q = np.empty(3)
    for i in range(lo, hi):                                                   # reflection of X[i], its partner
        s = 2.0 * (X[i, 0] * n[0] + X[i, 1] * n[1] + X[i, 2] * n[2] - d)
        q[0], q[1], q[2] = X[i, 0] - s * n[0], X[i, 1] - s * n[1], X[i, 2] - s * n[2]
        if tpoints.shape[1]:
            j = nearest_tree(tpoints, ids, nodes, split, 0, q, pair[i], stack, bound)
        else:
            j = nearest_brute(soa, centre, 0, q, dist, bits)
        pair[i] = j
        d2[i] = (X[j, 0] - q[0]) ** 2 + (X[j, 1] - q[1]) ** 2 + (X[j, 2] - q[2]) ** 2


@njit(cache=True)
def _plane_from_pairs(X, pair, d2, n, n0, trim) -> tuple:
    """One mirror-plane update from the closest ``trim`` of the pairs X[i] ↔ X[pair[i]]: (normal [3] signed like
    ``n``, offset, cosine of its angle to ``n0``)."""
    cut = np.quantile(np.sqrt(d2), trim)
    S, mid, kept = np.zeros((3, 3)), np.zeros(3), 0
    for i in range(len(X)):                                                   # the closest pairs a ↔ b
        if np.sqrt(d2[i]) <= cut:
            j = pair[i]
            for a in range(3):
                mid[a] += 0.5 * (X[i, a] + X[j, a])
                for b in range(3):
                    S[a, b] += (X[i, a] - X[j, a]) * (X[i, b] - X[j, b])
            kept += 1
    v = top_eigenvector(S)                                                    # dominant pair direction
    sign = v[0] * n[0] + v[1] * n[1] + v[2] * n[2]
    cand = v * (-1.0 if sign < 0.0 else 1.0)                                   # signed like n
    d_new = (mid[0] * cand[0] + mid[1] * cand[1] + mid[2] * cand[2]) / kept
    return cand, d_new, cand[0] * n0[0] + cand[1] * n0[1] + cand[2] * n0[2]


@njit(cache=True)
def _centroid_offset(X, n) -> float:
    """Offset of the plane with normal ``n`` through the centroid of ``X`` [P, 3]."""
    return X[:, 0].mean() * n[0] + X[:, 1].mean() * n[1] + X[:, 2].mean() * n[2]


class _Pairing:
    """The reflect-and-pair pass over one cloud ``X`` [P, 3] float64: its index, the pairs (warm-started between
    passes) and their squared distances. The pass (one nearest-neighbour query per point) runs in parts side by side
    (``equipose.core.parallel``: the caller's ``kernel_workers`` scope); the result does not depend on the number of
    parts."""

    def __init__(self, X):
        self.X = X
        self.index = build_index(X[None])
        self.pair, self.d2 = np.full(len(X), -1, np.int64), np.empty(len(X))
        self.parts = split_ranges(len(X), workers())

    def __call__(self, n, d) -> None:
        run_parts(_reflect_and_pair, [(self.index, n, d, lo, hi, self.pair, self.d2) for lo, hi in self.parts])


def _mirror_iterations(pairing, n0, n, d, first, iters, cos_max, trim, step) -> tuple:
    """Iterations ``first`` … ``first + iters − 1`` of ``mirror_plane`` on ``pairing``'s cloud from the plane (n, d):
    (normal [3], offset); they end early at the bound or a fixed point."""
    for k in range(first, first + iters):
        pairing(n, d)
        cand, d_new, cos0 = _plane_from_pairs(pairing.X, pairing.pair, pairing.d2, n, n0, trim)
        if cos0 < cos_max:
            return n, d
        if d_new == d and np.all(cand == n):                                  # a fixed point: every further
            return n, d                                                       # iteration repeats this one
        if k > 0 and step != 1.0:                     # the plane creeps in one direction: go ``step`` times as far
            ext = n + step * (cand - n)
            ext /= np.linalg.norm(ext)
            if ext @ n0 >= cos_max:                                           # within the bound
                cand, d_new = ext, d + step * (d_new - d)
        n, d = cand, d_new
    return n, d


def mirror_plane(points, normal, max_deg: float = MAX_DEG, iters: int = MIRROR_ITERS, step: float = MIRROR_STEP,
                 coarse: int = 1) -> tuple:
    """Mirror plane of ``points`` near the plane through their centroid with unit normal ``normal`` [3].

    Each iteration reflects the cloud, pairs every point with its nearest neighbour among the reflections' sources
    (the closest ``_MIRROR_TRIM`` of pairs), and takes the new normal as the dominant direction of the pair differences
    and the offset from their midpoints. Like point-to-point ICP the plane creeps towards the fixed point by small
    steps, so every update after the first is over-relaxed: the plane moves ``step`` times that update (where this
    stays within the bound; chair and car, complete: the same 5° accuracy in about half the iterations). Stops before
    a step that would leave ``max_deg`` of ``normal``, and at a fixed point (a step that returns the plane it started
    from). ``coarse`` > 1, coarse to fine: all but the last ``MIRROR_FINE`` iterations pair every ``coarse``-th
    point among themselves, the last ones and the residual use the whole cloud: at stride 3 and 8 iterations the
    queries of about 5 passes over the whole cloud instead of 9 (accuracy per model: docs/benchmarks.md, v0.43).
    Compiled queries (``equipose.core.nearest``), in parts side by side.
    Returns (unit normal [3] signed like ``normal``, offset d with the plane n·x = d, mean squared reflection
    residual).
    """
    P = np.ascontiguousarray(points, np.float64)                             # [P, 3]
    n0 = np.asarray(normal, np.float64) / np.linalg.norm(normal)
    if isinstance(coarse, bool) or int(coarse) != coarse or coarse < 1:
        raise ConfigError(f"mirror_plane coarse must be an int ≥ 1 (the stride of the early iterations' points), "
                          f"got {coarse!r}")
    cos_max, iters, step = float(np.cos(np.radians(max_deg))), int(iters), float(step)
    n, d = n0.copy(), _centroid_offset(P, n0)
    fine = min(iters, MIRROR_FINE) if coarse > 1 else iters
    if iters > fine:                                                          # the early iterations on a thinned cloud
        thin = _Pairing(np.ascontiguousarray(P[::int(coarse)]))              # [⌈P / coarse⌉, 3]
        n, d = _mirror_iterations(thin, n0, n, d, 0, iters - fine, cos_max, _MIRROR_TRIM, step)
    whole = _Pairing(P)
    n, d = _mirror_iterations(whole, n0, n, d, iters - fine, fine, cos_max, _MIRROR_TRIM, step)
    whole(n, d)                                                               # the residual of the final plane
    return n, float(d), float(whole.d2.mean())


def footprint_yaw(points, rotation, max_deg: float = MAX_DEG):
    """Turn about the pose's +z onto the nearest side of the cloud's minimum-area footprint rectangle.

    Returns (rotation [3, 3], turn in degrees), or (``rotation``, None) when the nearest side lies more than
    ``max_deg`` away.
    """
    P, R = _check(points, rotation)
    plane = np.stack([P @ R[:, 0], P @ R[:, 1]], axis=1).astype(np.float32)    # [P, 2] footprint in the pose's x, y
    _, _, angle = cv2.minAreaRect(plane)
    turn = (float(angle) + 45.0) % 90.0 - 45.0                                # nearest side, [-45, 45)
    if abs(turn) > max_deg:
        return R, None
    c, s = np.cos(np.radians(turn)), np.sin(np.radians(turn))
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return R @ Rz, turn


def apply_frame_priors(points, rotation, spec: dict, keep_up=None, mirror_iters: int = MIRROR_ITERS,
                       mirror_coarse: int = 1) -> tuple:
    """Run the steps of ``spec`` ({"steps": [...], "mirror_axis": "x"|"y"|"z", "max_deg": float}) in order.

    ``keep_up``: a camera-frame unit direction the pose's +z must keep (the caller's up prior): the mirror step then
    turns only about it. ``mirror_iters``, ``mirror_coarse``: ``mirror_plane``'s ``iters`` and ``coarse``.
    Returns (rotation [3, 3], {step: degrees turned, or None where the step left the pose}).
    """
    P, R = _check(points, rotation)
    steps = spec.get("steps") if isinstance(spec, dict) else None
    if not steps or any(st not in FRAME_PRIOR_STEPS for st in steps) or \
            ("mirror" in steps and spec.get("mirror_axis") not in _AXES):
        raise ConfigError(f"frame priors: spec must be {{'steps': some of {list(FRAME_PRIOR_STEPS)}, 'mirror_axis': "
                          f"'x'|'y'|'z' (for mirror), 'max_deg': float}}, got {spec!r}")
    max_deg = float(spec.get("max_deg", MAX_DEG))
    turned = {}
    for step in steps:
        if step == "footprint":
            R, turned[step] = footprint_yaw(P, R, max_deg)
        elif step == "rest":
            up = rest_facet_up(P, R[:, 2], max_deg)
            turned[step] = None if up is None else float(axis_angle_deg(up, R[:, 2]))
            if up is not None:
                R = rotation_between(R[:, 2], up) @ R
        else:                                                                # mirror
            a = _AXES[spec["mirror_axis"]]
            n, _, _ = mirror_plane(P, R[:, a], max_deg, iters=mirror_iters, coarse=mirror_coarse)
            if keep_up is not None:
                up = np.asarray(keep_up, np.float64)
                n = n - (n @ up) * up
                if a == 2 or np.linalg.norm(n) < 1e-9:                       # nothing to turn about up
                    turned[step] = None
                    continue
            turned[step] = float(axis_angle_deg(n, R[:, a]))
            R = rotation_between(R[:, a], n) @ R
    return nearest_rotation(R), turned
