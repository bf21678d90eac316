"""Stage ``rest_facet`` (metadata ``rest_facet``, complete-shape models): "up" read off the hull face the cloud rests
on near the selected pose's up axis (``equipose.runtime.rest_facet``); stage ``upright`` then re-selects with it,
keeping the selected azimuth.

Convention: model units, centred camera frame; up is a unit camera-frame direction.
"""
from __future__ import annotations

from equipose.runtime.rest_facet import rest_facet_up
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["RestFacetStage"]


@register_stage
class RestFacetStage(Stage):
    name = "rest_facet"
    metadata_key = "rest_facet"
    after = "polish"

    def __init__(self, tolerance_deg: float):
        self.tolerance_deg = float(tolerance_deg)

    @classmethod
    def build(cls, spec, options, context):
        rest = spec.get(cls.metadata_key)
        return None if rest is None else cls(rest["tolerance_deg"])

    def describe(self) -> dict:
        return {"tolerance_deg": self.tolerance_deg}

    def run(self, state: ObjectState) -> None:
        if state.up is not None or state.selection is None:
            return
        up = rest_facet_up(state.points, state.rotation[:, 2], self.tolerance_deg)
        if up is not None:
            state.up, state.up_source = up, "rest_facet"
