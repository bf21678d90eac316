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
``score_sets`` is the numpy reference; the stage runs the same layers as a small onnxruntime graph (``TurnScorer``:
its sets in parts side by side within the estimator's thread budget, one one-thread session per part).
"""
from __future__ import annotations

import numpy as np

from equipose.core.parallel import MAX_WORKERS, run_parts, split_ranges
from equipose.runtime.hypotheses import HALF_TURNS

__all__ = ["TURN_POINTS", "turned_sets", "score_sets", "turn_scores", "TurnScorer"]

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


class TurnScorer:
    """``score_sets`` as an in-memory onnxruntime graph (MatMul + Add + Relu per layer, max and mean pooling): the
    same scores to float32 rounding. Call with sets [S, n, 3] → scores [S]. With ``threads`` > 1 the sets run in
    parts side by side, each on its own one-thread session (a part's scores do not depend on the split; one session
    with intra-op threads gained nothing on this small graph)."""

    def __init__(self, weights: dict, threads: int = 1):
        import onnxruntime as ort

        from equipose.runtime.session import session_options

        graph = _scorer_graph(weights)
        count = max(1, min(int(threads), MAX_WORKERS, 1 + len(HALF_TURNS)))                  # at most one per set
        self.sessions = [ort.InferenceSession(graph, sess_options=session_options(1),
                                              providers=["CPUExecutionProvider"]) for _ in range(count)]

    def __call__(self, sets: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(sets, np.float32)                                         # [S, n, 3]
        parts = split_ranges(len(x), len(self.sessions))
        outs = run_parts(lambda sess, part: sess.run(None, {"sets": part})[0][:, 0],
                         [(sess, x[a:b]) for sess, (a, b) in zip(self.sessions, parts)])
        return np.concatenate(outs)                                                        # [S]


def _scorer_graph(weights: dict) -> bytes:
    """The serialized ONNX graph of ``score_sets``: input ``sets`` [S, n, 3] float32, output ``scores`` [S, 1]."""
    from onnx import TensorProto, helper, numpy_helper

    nodes, inits = [], [numpy_helper.from_array(np.array([-2], np.int64), "pool_axis")]
    x = "sets"

    def dense(layers, x, prefix, last_relu):
        for k, (W, b) in enumerate(layers):
            w, bias = f"{prefix}{k}_w", f"{prefix}{k}_b"
            inits.extend([numpy_helper.from_array(np.ascontiguousarray(np.asarray(W, np.float32).T), w),
                          numpy_helper.from_array(np.asarray(b, np.float32), bias)])
            nodes.extend([helper.make_node("MatMul", [x, w], [f"{prefix}{k}_m"]),
                          helper.make_node("Add", [f"{prefix}{k}_m", bias], [f"{prefix}{k}_a"])])
            x = f"{prefix}{k}_a"
            if last_relu or k < len(layers) - 1:
                nodes.append(helper.make_node("Relu", [x], [f"{prefix}{k}_r"]))
                x = f"{prefix}{k}_r"
        return x

    f = dense(weights["point"], x, "point", last_relu=True)                                # [S, n, F]
    nodes.extend([helper.make_node("ReduceMax", [f, "pool_axis"], ["pool_max"], keepdims=0),
                  helper.make_node("ReduceMean", [f, "pool_axis"], ["pool_mean"], keepdims=0),
                  helper.make_node("Concat", ["pool_max", "pool_mean"], ["pooled"], axis=-1)])   # [S, 2F]
    out = dense(weights["head"], "pooled", "head", last_relu=False)                        # [S, 1]
    nodes.append(helper.make_node("Identity", [out], ["scores"]))
    graph = helper.make_graph(nodes, "turn_classifier",
                              [helper.make_tensor_value_info("sets", TensorProto.FLOAT, ["sets", "points", 3])],
                              [helper.make_tensor_value_info("scores", TensorProto.FLOAT, ["sets", 1])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 9
    return model.SerializeToString()
