"""Hypothesis selection over the 60 rotation hypotheses, calibrated frame correction, and symmetry handling.

Convention:
    Hypotheses are ``rotations`` [60, 3, 3], ``translations`` [60, 3] (model units) and ``scores`` [60] (lower is
    better), all for one object, as the ONNX model outputs them. Rotations act on column vectors:
    ``x_cam = R @ x_obj + t``. Calibration (from metadata) maps the learned frame to the category frame:
    ``R_cat = R_pred · δRᵀ``, ``t_cat = t_pred − R_cat · δt`` (δt in model units).
    Symmetry strings: ``"none"``, ``"continuous:<x|y|z>"`` (rotation about that object axis changes nothing),
    ``"discrete:<x|y|z><n>"`` (n-fold about that axis, e.g. ``discrete:z2``). Distances between hypotheses are taken
    modulo the category symmetry.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from equipose.core.errors import InvalidPointsError
# the symmetry math lives in equipose.core.symmetry; re-exported here for existing callers
from equipose.core.symmetry import (HALF_TURNS, _axis_rotations, canonicalise_rotation,  # noqa: F401
                                    parse_symmetry, symmetric_distance_deg)

__all__ = ["Selection", "apply_calibration", "parse_symmetry", "symmetric_distance_deg", "select_hypothesis",
           "canonicalise_rotation", "CONFIDENCE_MIN_ANGLE_DEG", "FLIP_MIN_ANGLE_DEG", "AMBIGUOUS_MARGIN", "HALF_TURNS"]

CONFIDENCE_MIN_ANGLE_DEG = 30.0   # the runner-up for the confidence margin must differ by more than this
FLIP_MIN_ANGLE_DEG = 150.0        # a "flip" is a hypothesis at least this far (≈ 180°) from the best
AMBIGUOUS_MARGIN = 0.1            # flip whose relative score margin is below this → ambiguous


@dataclass
class Selection:
    """Outcome of selecting among the hypotheses of one object.

    Attributes:
        index: chosen hypothesis (0..59).
        score: its score (model units², lower better).
        confidence: relative margin to the best hypothesis differing by > 30° (modulo symmetry):
            ``(s_alt − s_best) / s_alt`` in [0, 1]; 1 when no such hypothesis exists.
        ambiguous: True when a hypothesis ≈ 180° away (≥ 150°) scores within ``AMBIGUOUS_MARGIN`` (relative) of the
            best — a likely front/back or upside-down flip.
        runner_up: index of the best hypothesis > 30° away (or -1); runner_up_angle_deg its distance.
        flip: index of the best ≈180° hypothesis (or -1); flip_margin its relative margin.
        top_k: list of ``{"index", "score", "angle_deg"}`` (angle to the best, modulo symmetry), best first.
    """
    index: int
    score: float
    confidence: float
    ambiguous: bool
    runner_up: int = -1
    runner_up_angle_deg: float = float("nan")
    flip: int = -1
    flip_margin: float = float("nan")
    top_k: list = field(default_factory=list)


def _check_hypotheses(rotations, translations, scores):
    R = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    s = np.asarray(scores, np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (R.shape[0], 3) or s.shape != (R.shape[0],):
        raise InvalidPointsError(f"hypotheses must be rotations [A, 3, 3], translations [A, 3], scores [A]; got "
                                 f"{R.shape}, {t.shape}, {s.shape}")
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t)) and np.all(np.isfinite(s))):
        raise InvalidPointsError("the model produced NaN/Inf hypotheses; check the input points (scale, NaNs) and "
                                 "that the model file is intact")
    return R, t, s


def apply_calibration(rotations, translations, delta_R, delta_t):
    """Learned frame → category frame.

    Convention: ``rotations`` [..., 3, 3], ``translations`` [..., 3] model units; ``delta_R`` [3, 3], ``delta_t`` [3]
    model units. Returns (R_cat [..., 3, 3], t_cat [..., 3]) with ``R_cat = R · δRᵀ``, ``t_cat = t − R_cat · δt``.
    """
    R = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    dR = np.asarray(delta_R, np.float64).reshape(3, 3)
    dt = np.asarray(delta_t, np.float64).reshape(3)
    R_cat = R @ dR.T                                                            # [..., 3, 3]
    t_cat = t - R_cat @ dt                                                      # [..., 3]
    return R_cat, t_cat


def select_hypothesis(rotations, translations, scores, *, symmetry: str = "none", top_k: int = 5,
                      min_angle_deg: float = CONFIDENCE_MIN_ANGLE_DEG, flip_angle_deg: float = FLIP_MIN_ANGLE_DEG,
                      ambiguous_margin: float = AMBIGUOUS_MARGIN, prefer: int | None = None,
                      prefer_margin: float = 0.0) -> Selection:
    """Pick the best hypothesis and say how sure that choice is.

    Convention: ``rotations`` [A, 3, 3] (category frame, i.e. after calibration), ``translations`` [A, 3],
    ``scores`` [A] (lower better). ``prefer`` (tracking): a hypothesis index, or a previous rotation [3, 3] (then the
    hypothesis nearest to it, modulo symmetry); it is kept instead of the argmin when its relative score margin to the
    argmin is below ``prefer_margin``.
    Returns a ``Selection`` (see there for confidence / ambiguity definitions).
    """
    R, t, s = _check_hypotheses(rotations, translations, scores)
    A = len(s)
    best = int(np.argmin(s))
    if prefer is not None and np.ndim(prefer) == 2:                             # previous rotation [3, 3]
        prefer = int(np.argmin(symmetric_distance_deg(np.asarray(prefer, np.float64), R, symmetry)))
    if prefer is not None and 0 <= prefer < A and prefer != best:
        rel = (s[prefer] - s[best]) / max(abs(s[prefer]), 1e-12)
        if rel < prefer_margin:
            best = int(prefer)
    s_best = float(s[best])
    dist = symmetric_distance_deg(R[best], R, symmetry)                         # [A] degrees
    far = np.nonzero(dist > min_angle_deg)[0]
    sel = Selection(index=best, score=s_best, confidence=1.0, ambiguous=False)
    if len(far):
        j = int(far[np.argmin(s[far])])
        s_alt = float(s[j])
        sel.runner_up, sel.runner_up_angle_deg = j, float(dist[j])
        sel.confidence = float(np.clip((s_alt - s_best) / max(abs(s_alt), 1e-12), 0.0, 1.0))
    flips = np.nonzero(dist >= flip_angle_deg)[0]
    if len(flips):
        f = int(flips[np.argmin(s[flips])])
        sel.flip = f
        sel.flip_margin = float((s[f] - s_best) / max(abs(s[f]), 1e-12))
        sel.ambiguous = bool(sel.flip_margin < ambiguous_margin)
    order = np.argsort(s, kind="stable")[: max(0, int(top_k))]
    sel.top_k = [{"index": int(i), "score": float(s[i]), "angle_deg": float(dist[i])} for i in order]
    return sel
