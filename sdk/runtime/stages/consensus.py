"""Stage ``consensus``: the rotated copies' consensus pose takes the place of its nearest hypothesis and ranks first
(with its ICP residual when re-scored, else that hypothesis' score). Runs wherever stage ``copies`` does.

Convention: model units, learned frame; distances modulo the category symmetry.
"""
from __future__ import annotations

import numpy as np

from equipose.runtime.hypotheses import symmetric_distance_deg
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["ConsensusStage"]


@register_stage
class ConsensusStage(Stage):
    name = "consensus"
    after = "rescore"

    @classmethod
    def build(cls, spec, options, context):
        return cls() if "copies" in context["built"] else None

    def run(self, state: ObjectState) -> None:
        R_c, t_c, _, s_c = state.consensus
        s = state.scores
        j = int(np.argmin(symmetric_distance_deg(R_c, state.R, state.symmetry)))
        s_c = s_c if state.rescored else s[j]
        others = np.delete(s, j)
        state.R[j], state.t[j] = R_c, t_c
        s[j] = s_c if not len(others) or s_c < others.min() else np.nextafter(others.min(), -np.inf)
