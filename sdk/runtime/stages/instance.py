"""Stage ``instance`` (instance-level mode, ``PoseEstimator(model_points=...)``): the object's own model points take
the place of the predicted shape (``equipose.runtime.instance``): every hypothesis gets a few ICP steps against them,
the ``k`` best go on to convergence, and the winner is composed back into the CAD frame. ``ambiguous`` also when a
turn of the winner about one of the model's principal axes fits within the flip margin (10 %) after a few ICP steps
(``equipose.runtime.instance.undecided_turn``): a turn about a symmetry axis that the view cannot decide.

Convention: model units, centred camera frame; the result is the CAD model's pose (camera ← CAD), no symmetry.
"""
from __future__ import annotations

import numpy as np

from equipose.runtime.hypotheses import AMBIGUOUS_MARGIN, select_hypothesis
from equipose.runtime.instance import COARSE_ITERS, undecided_turn
from equipose.runtime.refine import refine_hypotheses
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["InstanceStage"]


@register_stage
class InstanceStage(Stage):
    name = "instance"
    modes = ("instance",)
    after = "handle"

    def __init__(self, model, scale: float):
        self.model, self.scale = model, float(scale)

    @classmethod
    def build(cls, spec, options, context):
        return cls(context["instance"], spec.scale)

    def describe(self) -> dict:
        return {"k": self.model.k, "iters": self.model.iters, "template_points": len(self.model.template)}

    def run(self, state: ObjectState) -> None:
        inst = self.model
        R, t, s = refine_hypotheses(state.points, inst.template, state.R, state.t, state.scores, k=len(state.scores),
                                    iters=COARSE_ITERS, bidirectional=False)
        R, t, s = refine_hypotheses(state.points, inst.template, R, t, s, k=inst.k, iters=inst.iters,
                                    bidirectional=False)
        R_obj = np.einsum("aij,jk->aik", R, inst.A)                             # [60, 3, 3] CAD → camera
        t_obj = np.einsum("aij,j->ai", R, inst.b) + t                           # [60, 3] model units
        sel = select_hypothesis(R_obj, t_obj, s, symmetry="none", top_k=state.top_k, prefer=state.prefer,
                                prefer_margin=state.prefer_margin)
        # a turn of the chosen pose that fits almost as well (e.g. about a symmetry axis the view cannot decide)
        sel.ambiguous = bool(sel.ambiguous or undecided_turn(state.points, inst.template, R[sel.index],
                                                             t[sel.index], AMBIGUOUS_MARGIN))
        U, _, Vt = np.linalg.svd(R_obj[sel.index])
        state.R, state.t, state.scores, state.symmetry = R_obj, t_obj, s, "none"
        state.selection, state.confidence, state.ambiguous = sel, sel.confidence, sel.ambiguous
        state.set_pose(U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, t_obj[sel.index])
        state.canonical_category = inst.points_m / self.scale                   # [M, 3] CAD frame, model units
