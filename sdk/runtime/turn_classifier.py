"""The turn classifier: front/back (and upside down) decided by a small learned scorer of the view's canonical points
(model metadata ``turn_classifier``).

A partial view of a near-symmetric object (a car from the side, a sofa from behind or below) fits its half turn about
a category axis almost as well as its pose, and a fit to any template decides wrongly on part of those views (the
exact instance's own shape leaves 17 % of car views turned-better, ``tools/bench/flip_floor.py``). This stage asks a
PointNet instead: the view's points carried into the category frame by the pose, ``X = Rᵀ(x − t)``, and by each half
turn of it, ``H X``, are scored, and the pose takes the turn that scores highest when it wins by more than the file's
``margin`` (logits). The network was trained without pose labels, on the student's rendered training views carried by
the teacher's poses (``python -m equipose.train.turn_classifier``): the set the teacher poses scores highest.

Convention: ``model_points`` [N, 3] model units, centred camera frame (the model's input); ``translation`` [3] the
pose's translation in the same frame; rotations category → camera. Weights: ``{"point": [(W [o, i], b [o]), ...],
"head": [(W, b), ...]}`` float32, applied as ``x Wᵀ + b`` with ReLU between layers (none after the last head layer).
"""
from __future__ import annotations

import numpy as np

from equipose.runtime.hypotheses import HALF_TURNS

__all__ = ["TURN_POINTS", "turned_sets", "score_sets", "turn_scores"]

TURN_POINTS = 256            # observation points scored (a fixed, evenly spaced subset of the model input)


def turned_sets(model_points, rotation, translation, axes=("x", "y", "z"), points: int = TURN_POINTS) -> np.ndarray:
    """[1 + len(axes), n, 3] float32: the view's points in the pose's category frame (model units), then in that of
    each half turn ``R·H`` (= ``H X``, a half turn is its own inverse). ``n`` = min(points, N), evenly spaced along
    the input's order."""
    x = np.asarray(model_points, np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) < 1:
        raise ValueError(f"model_points must be [N ≥ 1, 3], got {x.shape}")
    idx = np.linspace(0, len(x) - 1, min(points, len(x))).round().astype(int)
    X = (x[idx] - np.asarray(translation, np.float64)) @ np.asarray(rotation, np.float64)   # [n, 3] Rᵀ(x − t)
    return np.stack([X] + [X @ HALF_TURNS[a].T for a in axes]).astype(np.float32)          # [1 + A, n, 3]


def _mlp(x: np.ndarray, layers, last_relu: bool) -> np.ndarray:
    for k, (W, b) in enumerate(layers):
        x = x @ W.T + b
        if last_relu or k < len(layers) - 1:
            x = np.maximum(x, 0.0)
    return x


def score_sets(weights: dict, sets: np.ndarray) -> np.ndarray:
    """Scores [...] (logits, higher = more likely the set as truly posed) of point sets [..., n, 3]."""
    f = _mlp(np.asarray(sets, np.float32), weights["point"], last_relu=True)          # [..., n, F]
    g = np.concatenate([f.max(-2), f.mean(-2)], -1)                                    # [..., 2F]
    return _mlp(g, weights["head"], last_relu=False)[..., 0]                           # [...]


def turn_scores(weights: dict, model_points, rotation, translation, axes=("x", "y", "z"),
                points: int = TURN_POINTS) -> np.ndarray:
    """[1 + len(axes)] scores of the pose and of its half turns about ``axes`` (``points`` of the view scored)."""
    return score_sets(weights, turned_sets(model_points, rotation, translation, axes, points))
