"""Stage ``handle`` (metadata ``handle``): the azimuth about a mug's axis from its observed handle
(``equipose.runtime.handle.resolve_handle``), which makes the pose full 6D (symmetry "none"). Result extras
``handle_visible`` (a handle was found, enough points lie in the handle zone — beyond both the canonical shape's
body and the body the camera sees, within a handle's reach — and at least ``HANDLE_MIN_CLUSTERED`` of them form a
surface patch),
``handle_points``, ``handle_direction_object``, ``handle_fit`` ((share, mass) of the fit that placed the handle, or
None: ``equipose.core.handles.HandleFit``); a handle not seen sets ``ambiguous``.

Convention: model units, category frame (z up = the symmetry axis; the handle along the metadata direction [3]).
"""
from __future__ import annotations

import numpy as np

from equipose.core.handles import (HANDLE_MAX_RATIO, HANDLE_MIN_CLUSTERED, HANDLE_MIN_FRACTION, HANDLE_MIN_POINTS,
                                   clustered_count, handle_zone_mask)
from equipose.runtime.handle import resolve_handle
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["HandleStage"]


@register_stage
class HandleStage(Stage):
    name = "handle"
    metadata_key = "handle"
    after = "axis_centre"

    def __init__(self, direction):
        self.direction = np.asarray(direction, np.float64)                     # [3] category frame

    @classmethod
    def build(cls, spec, options, context):
        d = spec.get(cls.metadata_key)
        return None if d is None else cls(d)

    def describe(self) -> dict:
        return {"direction": self.direction.tolist()}

    def run(self, state: ObjectState) -> None:
        R, found, fit = resolve_handle(self.direction, state.points, state.rotation, state.translation)
        observed = (np.asarray(state.points, np.float64) - state.translation) @ R          # [N, 3] category frame
        zone = handle_zone_mask(observed, state.canonical_category, self.direction, HANDLE_MAX_RATIO,
                                observed_body=True)                                         # [N]
        count = int(np.count_nonzero(zone))
        visible = bool(found and count >= max(HANDLE_MIN_POINTS, HANDLE_MIN_FRACTION * len(observed))
                       and clustered_count(observed, zone) >= HANDLE_MIN_CLUSTERED)
        state.symmetry = "none"                                                 # the handle fixes the azimuth
        state.set_pose(R)
        state.extras.update(handle_visible=visible, handle_points=int(count),
                            handle_direction_object=self.direction.copy(),
                            handle_fit=(float(fit.share), float(fit.mass)) if found else None)
        state.ambiguous = bool(state.ambiguous or not visible)
