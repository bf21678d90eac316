"""Stage ``frame_priors`` (metadata ``frame_priors``, complete-shape models): the pose turned onto the cloud's mirror
plane / footprint / resting face within a bound (``equipose.runtime.frame_priors``); a given up prior is kept.
Result extra ``frame_priors``: degrees each step turned the pose. Options: ``points`` "cloud" (every point of the crop),
"input" (the model input's N points) or n (the crop thinned to at most n points); ``mirror_iters``: iterations of the
mirror-plane fit ("auto": ``equipose.runtime.frame_priors.MIRROR_ITERS``); ``mirror_coarse``: the stride of the points
its early iterations pair (1: every iteration on every point; ``equipose.runtime.frame_priors.mirror_plane``).

Convention: model units, centred camera frame; rotation category → camera.
"""
from __future__ import annotations

from equipose.runtime.frame_priors import MIRROR_ITERS, apply_frame_priors
from equipose.runtime.stage import ObjectState, Stage, cloud_points_option, int_option, register_stage

__all__ = ["FramePriorsStage"]


@register_stage
class FramePriorsStage(Stage):
    name = "frame_priors"
    metadata_key = "frame_priors"
    after = "upright"
    options = {"points": "cloud", "mirror_iters": "auto", "mirror_coarse": 1}

    def __init__(self, spec: dict, points: str | int = "cloud", mirror_iters: int = MIRROR_ITERS,
                 mirror_coarse: int = 1):
        self.spec, self.points, self.mirror_iters, self.mirror_coarse = spec, points, mirror_iters, mirror_coarse

    @classmethod
    def build(cls, spec, options, context):
        fp = spec.get(cls.metadata_key)
        points = cloud_points_option("frame_priors", options["points"])
        iters, coarse = options["mirror_iters"], options["mirror_coarse"]
        iters = MIRROR_ITERS if iters == "auto" else int_option("frame_priors mirror_iters", iters, 1, None,
                                                                 "iterations of the mirror-plane fit")
        coarse = int_option("frame_priors mirror_coarse", coarse, 1, None, "the stride of the points the "
                            "mirror-plane fit's early iterations pair; 1: every point")
        return None if fp is None else cls(fp, points, iters, coarse)

    def describe(self) -> dict:
        return {"steps": list(self.spec["steps"]), "points": self.points, "mirror_iters": self.mirror_iters,
                "mirror_coarse": self.mirror_coarse}

    def run(self, state: ObjectState) -> None:
        keep_up = state.up if state.up_source == "given" else None
        x = state.cloud_points(self.points)                                     # [P', 3]
        R, turned = apply_frame_priors(x, state.rotation, self.spec, keep_up=keep_up, mirror_iters=self.mirror_iters,
                                       mirror_coarse=self.mirror_coarse)
        state.set_pose(R)
        state.extras["frame_priors"] = turned

