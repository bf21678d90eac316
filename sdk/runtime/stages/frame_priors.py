"""Stage ``frame_priors`` (metadata ``frame_priors``, complete-shape models): the pose turned onto the cloud's mirror
plane / footprint / resting face within a bound (``equipose.runtime.frame_priors``); a given up prior is kept.
Result extra ``frame_priors``: degrees each step turned the pose. Options: ``points`` "cloud" (every point of the crop),
"input" (the model input's N points) or n (the crop thinned to at most n points); ``mirror_iters``: iterations of the
mirror-plane fit ("auto": ``equipose.runtime.frame_priors.MIRROR_ITERS``).

Convention: model units, centred camera frame; rotation category → camera.
"""
from __future__ import annotations

from equipose.core.errors import ConfigError
from equipose.runtime.frame_priors import MIRROR_ITERS, apply_frame_priors
from equipose.runtime.stage import ObjectState, Stage, cloud_points_option, register_stage

__all__ = ["FramePriorsStage"]


@register_stage
class FramePriorsStage(Stage):
    name = "frame_priors"
    metadata_key = "frame_priors"
    after = "upright"
    options = {"points": "cloud", "mirror_iters": "auto"}

    def __init__(self, spec: dict, points: str | int = "cloud", mirror_iters: int = MIRROR_ITERS):
        self.spec, self.points, self.mirror_iters = spec, points, mirror_iters

    @classmethod
    def build(cls, spec, options, context):
        fp = spec.get(cls.metadata_key)
        points = cloud_points_option("frame_priors", options["points"])
        iters = options["mirror_iters"]
        if isinstance(iters, str) and iters == "auto":
            iters = MIRROR_ITERS
        elif isinstance(iters, bool) or not isinstance(iters, int) or iters < 1:
            raise ConfigError(f"frame_priors mirror_iters must be 'auto' or an int ≥ 1 (iterations of the "
                              f"mirror-plane fit), got {iters!r}")
        return None if fp is None else cls(fp, points, iters)

    def describe(self) -> dict:
        return {"steps": list(self.spec["steps"]), "points": self.points, "mirror_iters": self.mirror_iters}

    def run(self, state: ObjectState) -> None:
        keep_up = state.up if state.up_source == "given" else None
        x = state.cloud_points(self.points)                                     # [P', 3]
        R, turned = apply_frame_priors(x, state.rotation, self.spec, keep_up=keep_up, mirror_iters=self.mirror_iters)
        state.set_pose(R)
        state.extras["frame_priors"] = turned
