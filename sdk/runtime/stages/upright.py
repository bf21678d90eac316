"""Stage ``upright``: selection under the up prior (``equipose.runtime.upright.select_upright``): hypotheses near
"up" are turned onto it and fitted by ICP with the rotation held about it. Runs when the caller gave ``up`` (the
starts: every hypothesis near up) or stage ``rest_facet`` found one (the start: the selected hypothesis).

Option ``points``: observation points fitted ("all", or the first n of the FPS-ordered model input).

Convention: category frame, model units, centred camera frame; up a unit camera-frame direction.
"""
from __future__ import annotations

from equipose.core.errors import ConfigError
from equipose.core.geometry import nearest_rotation
from equipose.runtime.stage import ObjectState, Stage, register_stage
from equipose.runtime.upright import select_upright

__all__ = ["UprightStage"]


@register_stage
class UprightStage(Stage):
    name = "upright"
    after = "rest_facet"
    options = {"points": "all"}

    def __init__(self, bidirectional: bool, points: int | None = None):
        self.bidirectional, self.points = bidirectional, points

    @classmethod
    def build(cls, spec, options, context):
        n = options["points"]
        if n != "all" and (isinstance(n, bool) or not isinstance(n, int) or n < 16):
            raise ConfigError(f"upright points must be 'all' or an int ≥ 16, got {n!r}")
        return cls(not spec.partial, None if n == "all" else n)

    def describe(self) -> dict:
        return {"points": self.points or "all"}

    def run(self, state: ObjectState) -> None:
        if state.up is None:
            return
        starts = [state.selection.index] if state.up_source == "rest_facet" else None
        x = state.points if self.points is None else state.points[: self.points]   # FPS prefix: an even subsample
        sel, R, t = select_upright(x, state.canonical_category, state.R, state.t, state.scores, state.up,
                                   symmetry=state.symmetry, top_k=state.top_k, bidirectional=self.bidirectional,
                                   starts=starts)
        state.selection, state.confidence, state.ambiguous = sel, sel.confidence, sel.ambiguous
        state.set_pose(nearest_rotation(R), t)
