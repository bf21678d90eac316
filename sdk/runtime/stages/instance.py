"""Stage ``instance`` (instance-level mode, ``PoseEstimator(model_points=...)``): the object's own model points take the
place of the predicted shape (``equipose.runtime.instance``), coarse to fine: every hypothesis gets a few ICP steps
(part of the view against part of the model), the ``k`` best converge point-to-plane against part of the model, the
``FINE_K`` best of those against all of it (then a point-to-point polish), and the winner is composed back into the
CAD frame. The winner's turns about the model's principal axes get a few ICP steps
(``equipose.runtime.instance.turned_fits``): one that fits better is converged and takes the winner's place when it
ends better (``better_turn``: the hypotheses can all miss the true pose's basin), and ``ambiguous`` is also set when
one fits within the flip margin (10 %): a turn about a symmetry axis that the view cannot decide (``undecided_turn``).
Before the turns, where the winner's truncated residual (crop points farther than ``TRIM_M`` from the model count as
``TRIM_M``) exceeds ``TRIM_GATE`` × ``TRIM_M``², i.e. much of the crop lies off the model, a trimmed search
(``trimmed_search``: every coarse start again, point-to-plane with those points left out) takes the winner's place
where its truncated residual is lower: the points of a neighbour in the crop pull every untrimmed pose (result extra
``trimmed``); its pose then skips ``better_turn``, whose residuals are untrimmed.

Convention: model units, centred camera frame; the result is the CAD model's pose (camera ← CAD), no symmetry.
"""
from __future__ import annotations

import numpy as np

from equipose.core.icp import icp_point_to_plane
from equipose.runtime.hypotheses import AMBIGUOUS_MARGIN, select_hypothesis
from equipose.runtime.instance import (COARSE_ITERS, COARSE_POINTS, CONVERGED_STEP, FINE_K, POLISH_ITERS,
                                       SUB_TEMPLATE_POINTS, TRIM_GATE, TRIM_M, TURN_CONVERGE_ITERS, better_turn,
                                       trimmed_search, turned_fits, undecided_turn)
from equipose.runtime.refine import refine_hypotheses
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["InstanceStage"]


@register_stage
class InstanceStage(Stage):
    name = "instance"
    modes = ("instance",)
    after = "seat"

    def __init__(self, model, scale: float):
        self.model, self.scale = model, float(scale)

    @classmethod
    def build(cls, spec, options, context):
        return cls(context["instance"], spec.scale)

    def describe(self) -> dict:
        return {"k": self.model.k, "iters": self.model.iters, "template_points": len(self.model.template)}

    def run(self, state: ObjectState) -> None:
        inst = self.model
        x, Y = state.points, inst.template                                      # FPS-ordered: prefixes are even
        R, t, s = refine_hypotheses(x[:COARSE_POINTS], Y[:SUB_TEMPLATE_POINTS], state.R, state.t, state.scores,
                                    k=len(state.scores), iters=COARSE_ITERS, bidirectional=False)
        coarse = (R.copy(), t.copy())                                           # every start, for the trimmed search
        # the k best converge point-to-plane on part of the template, the FINE_K best of those on all of it; a
        # point-to-point polish of those gives the precision and the residual every hypothesis is ranked by
        R, t, s = refine_hypotheses(x, Y[:SUB_TEMPLATE_POINTS], R, t, s, k=inst.k, iters=inst.iters,
                                    normals=inst.normals[:SUB_TEMPLATE_POINTS], tol=CONVERGED_STEP)
        R, t, s = refine_hypotheses(x, Y, R, t, s, k=min(FINE_K, inst.k), iters=inst.iters, normals=inst.normals,
                                    tol=CONVERGED_STEP)
        R, t, s = refine_hypotheses(x, Y, R, t, s, k=min(FINE_K, inst.k), iters=POLISH_ITERS, bidirectional=False)
        R_obj = np.einsum("aij,jk->aik", R, inst.A)                             # [60, 3, 3] CAD → camera
        t_obj = np.einsum("aij,j->ai", R, inst.b) + t                           # [60, 3] model units
        sel = select_hypothesis(R_obj, t_obj, s, symmetry="none", top_k=state.top_k, prefer=state.prefer,
                                prefer_margin=state.prefer_margin)
        i = sel.index
        # what stands beside the object in its crop pulls every pose above; the trimmed search lets only the points
        # within TRIM_M of the model pull, from every start, and takes the winner's place where it fits more
        trim = TRIM_M / self.scale                                              # model units
        _, _, own = icp_point_to_plane(x, Y, inst.normals, R[i][None], t[i][None], iters=0, max_dist=trim)
        trimmed = False
        if own[0] > TRIM_GATE * trim ** 2:                                      # much of the crop off the model
            R_t, t_t, r_t = trimmed_search(x, Y, inst.normals, *coarse, trim)
            trimmed = r_t < float(own[0])
        state.extras["trimmed"] = bool(trimmed)
        if trimmed:
            R[i], t[i] = R_t, t_t
            R_obj[i], t_obj[i] = R[i] @ inst.A, R[i] @ inst.b + t[i]
        fits = turned_fits(state.points, inst.template, R[i], t[i], inst.normals)   # the winner's principal-axis turns
        better = None if trimmed else better_turn(state.points, inst.template, float(s[i]), fits, TURN_CONVERGE_ITERS)
        if better is not None:                                                  # a turn fits better: it wins
            R[i], t[i], s[i] = better
            R_obj[i], t_obj[i] = R[i] @ inst.A, R[i] @ inst.b + t[i]
            fits = turned_fits(state.points, inst.template, R[i], t[i], inst.normals)
        # a turn of the chosen pose that fits almost as well (e.g. about a symmetry axis the view cannot decide)
        sel.ambiguous = bool(sel.ambiguous or undecided_turn(state.points, inst.template, R[i], t[i],
                                                             AMBIGUOUS_MARGIN, fits=fits))
        U, _, Vt = np.linalg.svd(R_obj[i])
        state.R, state.t, state.scores, state.symmetry = R_obj, t_obj, s, "none"
        state.selection, state.confidence, state.ambiguous = sel, sel.confidence, sel.ambiguous
        state.set_pose(U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, t_obj[i])
        state.canonical_category = inst.points_m / self.scale                   # [M', 3] CAD frame, model units
