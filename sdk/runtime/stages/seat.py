"""Stage ``seat`` (metadata ``seat``): the centre of a container standing upright on the support plane set from the
height of its top.

A fitted pose places a cup's or bowl's centre by its shape, and on a single view that shape's height is the least
certain thing about it: the centre sits a few millimetres too high or too low, more so under the up prior, which
holds the axis and leaves only the centre to fit (docs/results/real/README.md, v0.43). The view itself gives the
height: a container standing on the plane reaches its top (``ObjectState.top_height``, the 95th percentile of its
crop points' heights above the plane), and its centre sits at a share of that height that varies little within a
category. Where the pose's category z lies within ``SEAT_DEG`` of the support plane's normal (with or without an up
prior, and after ``stand_upright`` turned a pose upright; after the handle), the centre moves along the normal to
the file's ``height`` × the top's height.

``seat`` JSON {"height": h, ...} holds h, the median share over the standing results of rendered training shapes
(``python -m equipose.train.evaluation.seat``). Option ``height``: "auto" (the file's; absent: the stage does not run),
a share in (0, 1], or "read" (report the reading, never move). Result extra where it applies: ``seat_reading``
{"top_height": m, "moved": m along the normal}.

Convention: model units, centred camera frame; the support plane's normal a unit camera-frame direction, heights in
metres above the plane.
"""
from __future__ import annotations

import math

from equipose.runtime.stage import ObjectState, ShareCapStage, register_stage

__all__ = ["SeatStage", "SEAT_DEG", "parse_seat"]

SEAT_DEG = 5.0                  # the pose's axis within this of the support plane's normal: standing on it
FIT_COMMAND = "python -m equipose.train.evaluation.seat --model ... --write"


@register_stage
class SeatStage(ShareCapStage):
    name = "seat"
    metadata_key = "seat"
    after = "handle"
    options = {"height": "auto"}
    share_key = "height"
    share_meaning = "the centre's height above the support plane per height of the object's top"
    fit_command = FIT_COMMAND

    def __init__(self, height: float | None):
        super().__init__(height)                                                # self.height; None: read only
        self.cos_min = math.cos(math.radians(SEAT_DEG))

    def run(self, state: ObjectState) -> None:
        if state.support_up is None or state.rotation is None:
            return
        up = state.support_up                                                   # [3] unit, camera frame
        if float(state.rotation[:, 2] @ up) < self.cos_min:                     # not standing upright on the plane
            return
        top = state.top_height()                                                # m above the plane
        if self.height is None or top <= 0.0:
            state.extras["seat_reading"] = {"top_height": top, "moved": 0.0}
            return
        t = state.at_height(state.translation, self.height * top)               # [3] model units
        moved = float((t - state.translation) @ up) * state.prep.scale          # m along the normal
        state.set_pose(state.rotation, t)
        state.extras["seat_reading"] = {"top_height": top, "moved": moved}


def parse_seat(text, source: str = "model") -> dict | None:
    """``seat`` metadata (JSON string or dict) → the dict with ``height`` a float in (0, 1], or None. Raises
    ``MetadataError`` when malformed (``parse_share_cap``)."""
    return SeatStage.parse(text, source)
