"""Stage ``frame_priors`` (metadata ``frame_priors``, complete-shape models): the pose turned onto the cloud's mirror
plane / footprint / resting face within a bound (``equipose.runtime.frame_priors``); a given up prior is kept.
Result extra ``frame_priors``: degrees each step turned the pose.

Convention: model units, centred camera frame; rotation category → camera.
"""
from __future__ import annotations

from equipose.runtime.frame_priors import apply_frame_priors
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["FramePriorsStage"]


@register_stage
class FramePriorsStage(Stage):
    name = "frame_priors"
    metadata_key = "frame_priors"
    after = "upright"

    def __init__(self, spec: dict):
        self.spec = spec

    @classmethod
    def build(cls, spec, options, context):
        fp = spec.get(cls.metadata_key)
        return None if fp is None else cls(fp)

    def describe(self) -> dict:
        return {"steps": list(self.spec["steps"])}

    def run(self, state: ObjectState) -> None:
        keep_up = state.up if state.up_source == "given" else None
        R, turned = apply_frame_priors(state.every_point, state.rotation, self.spec, keep_up=keep_up)
        state.set_pose(R)
        state.extras["frame_priors"] = turned
