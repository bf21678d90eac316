"""Stage ``flip`` (metadata ``flip_templates``): front/back (or upside down) settled by fitting category template
shapes from the pose and from its half turns (``equipose.runtime.flip.flip_scores``); under an up prior only the turn
about up. The pose takes the best fit's rotation when a turn wins; ``ambiguous`` says whether the fits decide.
Result extra ``flip_margin``.

Convention: model units, centred camera frame; templates [T, M, 3] category frame.
"""
from __future__ import annotations

import numpy as np

from equipose.runtime.flip import FLIP_AMBIGUOUS_MARGIN, flip_scores
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["FlipStage"]


@register_stage
class FlipStage(Stage):
    name = "flip"
    metadata_key = "flip_templates"
    after = "frame_priors"

    def __init__(self, templates, axes, partial: bool):
        self.templates, self.axes, self.partial = np.asarray(templates, np.float64), list(axes), partial

    @classmethod
    def build(cls, spec, options, context):
        ft = spec.get(cls.metadata_key)
        return None if ft is None else cls(ft["points"], ft["axes"], spec.partial)

    def describe(self) -> dict:
        return {"templates": len(self.templates), "axes": self.axes}

    def run(self, state: ObjectState) -> None:
        _, s, R_fit = flip_scores(state.points, state.rotation, state.translation, self.templates, axes=self.axes,
                                  up=state.up, partial=self.partial)
        order = np.argsort(s, kind="stable")
        margin = float((s[order[1]] - s[order[0]]) / max(s[order[1]], 1e-12)) if len(s) > 1 else 1.0
        if order[0] != 0:                                                       # turned: the template fit's rotation
            state.set_pose(R_fit[order[0]])
        state.ambiguous = margin < FLIP_AMBIGUOUS_MARGIN
        state.extras["flip_margin"] = margin
