"""Stage ``upright``: selection under the up prior (``equipose.runtime.upright.select_upright``): hypotheses near
"up" are turned onto it and fitted by ICP with the rotation held about it. Runs when the caller gave ``up`` (the
starts: every hypothesis near up) or stage ``rest_facet`` found one (the start: the selected hypothesis).

Convention: category frame, model units, centred camera frame; up a unit camera-frame direction.
"""
from __future__ import annotations

from equipose.core.geometry import nearest_rotation
from equipose.runtime.stage import ObjectState, Stage, register_stage
from equipose.runtime.upright import select_upright

__all__ = ["UprightStage"]


@register_stage
class UprightStage(Stage):
    name = "upright"
    after = "rest_facet"

    def __init__(self, bidirectional: bool):
        self.bidirectional = bidirectional

    @classmethod
    def build(cls, spec, options, context):
        return cls(not spec.partial)

    def run(self, state: ObjectState) -> None:
        if state.up is None:
            return
        starts = [state.selection.index] if state.up_source == "rest_facet" else None
        sel, R, t = select_upright(state.points, state.canonical_category, state.R, state.t, state.scores, state.up,
                                   symmetry=state.symmetry, top_k=state.top_k, bidirectional=self.bidirectional,
                                   starts=starts)
        state.selection, state.confidence, state.ambiguous = sel, sel.confidence, sel.ambiguous
        state.set_pose(nearest_rotation(R), t)
