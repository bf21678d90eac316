"""Stage ``select``: the best hypothesis by score, with its confidence and flip ambiguity
(``equipose.runtime.hypotheses.select_hypothesis``); tracking's preferred hypothesis wins within its margin. Under
the up prior stage ``upright`` selects instead.

Convention: category frame, model units; the pose is projected onto SO(3).
"""
from __future__ import annotations

from equipose.core.geometry import nearest_rotation
from equipose.runtime.hypotheses import select_hypothesis
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["SelectStage"]


@register_stage
class SelectStage(Stage):
    name = "select"
    after = "calibrate"

    def run(self, state: ObjectState) -> None:
        if state.up is not None:
            return
        margin = state.ambiguous_margin
        sel = select_hypothesis(state.R, state.t, state.scores, symmetry=state.symmetry, top_k=state.top_k,
                                prefer=state.prefer, prefer_margin=state.prefer_margin,
                                **({} if margin is None else {"ambiguous_margin": margin}))
        state.selection, state.confidence, state.ambiguous = sel, sel.confidence, sel.ambiguous
        state.set_pose(nearest_rotation(state.R[sel.index]), state.t[sel.index])
