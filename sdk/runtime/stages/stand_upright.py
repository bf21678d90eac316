"""Stage ``stand_upright`` (metadata ``upright_rest``): without an up prior, an open container posed on its opening is
stood upright where the end facing up reads open.

A pose that stands a cup, mug or bowl on its opening on the support plane under it (its category up axis z pointing
into the table) claims that the closed base faces up. Where ``equipose.core.opening.top_closure`` finds the end facing
up open instead (its ``bottom`` share, the points near the axis at the posed bottom, below the file's ``cap``), the
view contradicts the pose: an upright container posed upside down, the network's most common error on them. The stage
turns the pose over (a half turn about the category x axis) and refits its azimuth and centre with the axis held on the
support plane's normal (``equipose.runtime.upright.upright_icp``).

``upright_rest`` JSON {"cap": c, ...} holds c, chosen on rendered views where the turn fixes at least ten times as many
results as it breaks (``equipose.train.evaluation.rest_side --upright``). Option ``cap``: "auto" (the file's; absent:
the stage does not run), a share in (0, 1], or "read" (report the reading, never turn). Result extras where it reads:
``upright_reading`` {"bottom_cap": the share, "top_taper": how much the body widens towards the end on the table},
and ``rest`` "upright" where it turned the pose. Under an up prior the
stage does nothing (the prior holds the axis; stage ``rest_side`` decides there).

Convention: category frame, model units, centred camera frame; the support plane's normal a unit camera-frame
direction.
"""
from __future__ import annotations

from equipose.core.geometry import nearest_rotation
from equipose.runtime.stage import ObjectState, ShareCapStage, register_stage
from equipose.runtime.stages.rest_side import HALF_TURN_X
from equipose.runtime.upright import upright_icp

__all__ = ["StandUprightStage", "parse_upright_rest"]


@register_stage
class StandUprightStage(ShareCapStage):
    name = "stand_upright"
    metadata_key = "upright_rest"
    fit_command = "python -m equipose.train.evaluation.rest_side --upright --model ... --write"
    after = "rest_side"

    def run(self, state: ObjectState) -> None:
        if state.up is not None or state.support_up is None or state.rotation is None:
            return
        axis = state.rotation[:, 2]                                             # [3] the pose's category up
        if float(axis @ state.support_up) >= 0.0:                               # not posed on its opening
            return
        ends = state.closure()                                                  # the end facing up: ends.bottom
        state.extras["upright_reading"] = {"bottom_cap": ends.bottom, "top_taper": ends.taper}
        if self.cap is None or ends.bottom >= self.cap:
            return
        R, t, _ = upright_icp(state.points, state.canonical_category, (state.rotation @ HALF_TURN_X)[None],
                              state.translation[None], state.support_up)       # stood on its base, refitted
        state.set_pose(nearest_rotation(R[0]), t[0])
        state.extras["rest"] = "upright"


parse_upright_rest = StandUprightStage.parse     # ``upright_rest`` metadata → {"cap": share, ...} or None
