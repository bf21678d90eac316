"""Stage ``centre`` (metadata ``centre_calibration``): the reported centre moved along the camera ray by the model's
calibrated depth offset.

A single view shows the front of an object only. Fitting it places the centre of a partial view a few millimetres
nearer to the camera than it is, by about the same amount view after view (rendered cups and mugs: 7–10 mm, bowls
4–5 mm; docs/results/real/README.md, v0.40). ``centre_calibration`` JSON {"along_ray_m": b, ...} holds that offset,
fitted on rendered training views (``equipose.train.evaluation.centre``); this stage adds it along the ray from the
camera through the object's centre. It runs after ``confidence``, whose evidence reads the fitted pose.

Option ``offset``: "auto" (the file's ``along_ray_m``; absent: the stage does not run), or metres (0 = off).
Convention: model units, centred camera frame (the camera at ``−centre_m / scale``); metres in the metadata; positive
= away from the camera.
"""
from __future__ import annotations

import math

import numpy as np

from equipose.core.errors import ConfigError, MetadataError
from equipose.core.metadata import float_entry
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["CentreStage", "MAX_OFFSET_M", "parse_centre_calibration"]

MAX_OFFSET_M = 0.05         # |offset| above this is no calibration of a partial view's centre: refused


def parse_centre_calibration(text, source: str = "model") -> dict | None:
    """``centre_calibration`` metadata (JSON string or dict) → the dict with ``along_ray_m`` a float, or None.
    Raises ``MetadataError`` when malformed."""
    d = float_entry(text, "centre_calibration", "along_ray_m", source,
                    "python -m equipose.train.evaluation.centre --model ... --write")
    if d is None:
        return None
    b = d["along_ray_m"]
    if not (math.isfinite(b) and abs(b) <= MAX_OFFSET_M):
        raise MetadataError(f"{source}: centre_calibration along_ray_m must be finite and within ±{MAX_OFFSET_M} m, "
                            f"got {b}")
    return d


@register_stage
class CentreStage(Stage):
    name = "centre"
    metadata_key = "centre_calibration"
    after = "confidence"
    options = {"offset": "auto"}

    def __init__(self, offset_m: float):
        self.offset_m = float(offset_m)

    @classmethod
    def build(cls, spec, options, context):
        offset = options["offset"]
        if isinstance(offset, str) and offset == "auto":
            cal = parse_centre_calibration(spec.get(cls.metadata_key), spec.name)
            offset = None if cal is None else cal["along_ray_m"]
        elif isinstance(offset, bool) or not isinstance(offset, (int, float)) or not math.isfinite(offset) \
                or abs(offset) > MAX_OFFSET_M:
            raise ConfigError(f"centre offset must be 'auto' or metres within ±{MAX_OFFSET_M} (0 = off), got "
                              f"{offset!r}")
        return None if not offset else cls(offset)

    def describe(self) -> dict:
        return {"offset_m": self.offset_m}

    def run(self, state: ObjectState) -> None:
        if state.translation is None:                                           # no pose chosen
            return
        scale = float(state.prep.scale)                                         # metres per model unit
        ray = state.translation - state.prep.camera                             # [3] camera → object centre
        norm = float(np.linalg.norm(ray))
        if norm > 0.0:
            state.set_pose(state.rotation, state.translation + (self.offset_m / scale) * ray / norm)
