"""Stage ``rest_side`` (metadata ``upside_down_rest``): an open container under the up prior stood on its opening where
both the network and the view say so.

The up prior (stage ``upright``) holds the pose's axis on "up", the opening upwards: a bowl standing on its rim comes
out upright, 180° off. This stage turns the pose over (a half turn about the category x axis) and refits its azimuth
and centre with the axis held on "down" (``equipose.runtime.upright.upright_icp``) where two independent readings
agree that it stands the other way up:
- the network's own best hypothesis (lowest score, before the prior) has its up axis pointing down (cos < 0), and
- the upright pose's top reads closed: ``equipose.core.opening.top_closure``'s ``cap`` reaches the file's ``cap``.

``upside_down_rest`` JSON {"cap": c, ...} holds c, chosen on rendered views where the turn fixes at least ten times as
many results as it breaks (``equipose.train.evaluation.rest_side``). Option ``cap``: "auto" (the file's; absent: the
stage does not run), a share in (0, 1], or "read" (report the readings, never turn: what the fit collects). Result
extras under a prior: ``rest_reading`` {"own_up": cos of the network's own axis with up, "top_cap": the upright
pose's closed-top share}, and ``rest`` "upside_down" where it turned the pose.

Convention: category frame, model units, centred camera frame; ``up`` a unit camera-frame direction.
"""
from __future__ import annotations

import numpy as np

from equipose.core.geometry import nearest_rotation
from equipose.runtime.stage import ObjectState, ShareCapStage, register_stage
from equipose.runtime.upright import upright_icp

__all__ = ["RestSideStage", "parse_upside_down_rest", "HALF_TURN_X"]

HALF_TURN_X = np.diag([1.0, -1.0, -1.0])       # category frame: the opening (+z) turned down, x kept


@register_stage
class RestSideStage(ShareCapStage):
    name = "rest_side"
    metadata_key = "upside_down_rest"
    fit_command = "python -m equipose.train.evaluation.rest_side --model ... --write"
    after = "cylinder"

    def run(self, state: ObjectState) -> None:
        if state.up is None or state.rotation is None:
            return
        own = state.R[int(np.argmin(state.scores))]                            # [3, 3] the network's best, no prior
        own_up = float(own[:, 2] @ state.up)
        cap = state.closure().cap
        state.extras["rest_reading"] = {"own_up": own_up, "top_cap": cap}
        if self.cap is None or own_up >= 0.0 or cap < self.cap:
            return
        R, t, _ = upright_icp(state.points, state.canonical_category, (state.rotation @ HALF_TURN_X)[None],
                              state.translation[None], -state.up)              # stood on its opening, refitted
        state.set_pose(nearest_rotation(R[0]), t[0])
        state.extras["rest"] = "upside_down"


parse_upside_down_rest = RestSideStage.parse    # ``upside_down_rest`` metadata → {"cap": share, ...} or None
