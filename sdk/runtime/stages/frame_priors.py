"""Stage ``frame_priors`` (metadata ``frame_priors``, complete-shape models): the pose turned onto the cloud's mirror
plane / footprint / resting face within a bound (``equipose.runtime.frame_priors``); a given up prior is kept.
Result extra ``frame_priors``: degrees each step turned the pose. Option ``points``: "cloud" (every point of the crop)
or "input" (the model input's N points).

Convention: model units, centred camera frame; rotation category → camera.
"""
from __future__ import annotations

from equipose.core.errors import ConfigError
from equipose.runtime.frame_priors import apply_frame_priors
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["FramePriorsStage"]


@register_stage
class FramePriorsStage(Stage):
    name = "frame_priors"
    metadata_key = "frame_priors"
    after = "upright"
    options = {"points": "cloud"}

    def __init__(self, spec: dict, points: str = "cloud"):
        self.spec, self.points = spec, points

    @classmethod
    def build(cls, spec, options, context):
        fp = spec.get(cls.metadata_key)
        if options["points"] not in ("cloud", "input"):
            raise ConfigError(f"frame_priors points must be 'cloud' or 'input', got {options['points']!r}")
        return None if fp is None else cls(fp, options["points"])

    def describe(self) -> dict:
        return {"steps": list(self.spec["steps"]), "points": self.points}

    def run(self, state: ObjectState) -> None:
        keep_up = state.up if state.up_source == "given" else None
        x = state.every_point if self.points == "cloud" else state.points
        R, turned = apply_frame_priors(x, state.rotation, self.spec, keep_up=keep_up)
        state.set_pose(R)
        state.extras["frame_priors"] = turned
