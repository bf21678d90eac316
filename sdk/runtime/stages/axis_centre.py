"""Stage ``axis_centre`` (metadata ``axis_centre``; partial models of bodies of revolution: symmetry ``continuous:z``
or a ``handle``): the pose's symmetry axis moved, parallel to itself, to where the observed side normals meet it
(``equipose.core.revolution.axis_line``).

The network places the centre of a partial view from what it guesses of the unseen back; two crops of the same object
that differ by a few pixels at the edge (a box and the object's mask) moved it by 4 mm across the axis on the median
real Kinect can (mOSD, v0.46). The normals of the seen side fix the axis line by geometry alone. The height along
the axis is the network's. A fit that would move the axis by more than ``max_shift`` × the body's radius (its
canonical shape's median distance from the axis), or that the normals do not settle, leaves the pose as it is.
Result extra ``axis_shift_m``: how far the axis moved (metres; None where the stage left it).

The stage moves the centres that a model's confidence and centre calibrations are fitted on, so it runs where the
file says so (metadata ``axis_centre`` JSON {"points": ..., "max_shift": ...}, written by the release recipe's
``[axis_centre]`` table before those calibrations are fitted) or where asked:
``stages={"axis_centre": {"enabled": True}}``.

Options: ``enabled``: "auto" (the file's ``axis_centre`` entry present), True or False; ``points``: "auto" (the
file's, else "input"), "input" (the model input), "cloud" or an int (``cloud_points_option``); ``max_shift``: "auto"
(the file's, else 1) or a share of the body radius in (0, 2]. Runs after ``stand_upright`` and ``rim_axis`` (the axis
direction is final) and before ``handle``, whose body fit reads the axis at the pose's centre.

Convention: model units, centred camera frame; the symmetry axis is the pose's +z column through its translation.
"""
from __future__ import annotations

import json

import numpy as np

from equipose.core.errors import ConfigError, MetadataError
from equipose.core.normals import point_normals
from equipose.core.order_statistics import median
from equipose.core.revolution import axis_line
from equipose.runtime.stage import (NORMAL_NEIGHBOURS, ObjectState, Stage, cloud_points_option, enabled_option,
                                    entry_options, register_stage)

__all__ = ["AxisCentreStage", "parse_axis_centre", "DEFAULT_POINTS", "DEFAULT_MAX_SHIFT"]

DEFAULT_POINTS = "input"        # the model input's points (their normals are shared with ``cylinder``)
DEFAULT_MAX_SHIFT = 1.0         # the largest move, per body radius


@register_stage
class AxisCentreStage(Stage):
    name = "axis_centre"
    metadata_key = "axis_centre"
    after = "rim_axis"
    options = {"enabled": "auto", "points": "auto", "max_shift": "auto"}

    def __init__(self, points=DEFAULT_POINTS, max_shift: float = DEFAULT_MAX_SHIFT):
        self.points = points
        self.max_shift = float(max_shift)

    @classmethod
    def build(cls, spec, options, context):
        if not spec.partial or not (spec.symmetry == "continuous:z" or spec.get("handle") is not None):
            return None
        entry = parse_axis_centre(spec.get(cls.metadata_key), spec.name)
        if not enabled_option(cls.name, options["enabled"], entry):
            return None
        chosen = entry_options(options, entry or {"points": DEFAULT_POINTS, "max_shift": DEFAULT_MAX_SHIFT})
        points, shift = chosen["points"], chosen["max_shift"]
        if not _share(shift):
            raise ConfigError(f"axis_centre max_shift must be 'auto' or a share of the body radius in (0, 2], got "
                              f"{shift!r}")
        return cls(cloud_points_option(cls.name, points), float(shift))

    def describe(self) -> dict:
        return {"points": self.points, "max_shift": self.max_shift}

    def run(self, state: ObjectState) -> None:
        state.extras["axis_shift_m"] = None
        if state.rotation is None:
            return
        pts = state.cloud_points(self.points)                                   # [P, 3]
        normals = state.normals() if self.points == "input" else point_normals(pts, NORMAL_NEIGHBOURS)   # [P, 3]
        axis = state.rotation[:, 2]
        line = axis_line(pts, normals, axis, state.translation)
        if line is None:
            return
        shape = state.canonical_category                                        # [M, 3] category frame
        radius = median(np.hypot(shape[:, 0], shape[:, 1]))
        if line.shift > self.max_shift * radius:
            return
        state.set_pose(state.rotation, line.point)
        state.extras["axis_shift_m"] = line.shift * float(state.prep.scale)


def _share(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 < v <= 2.0


def parse_axis_centre(text, source: str = "model") -> dict | None:
    """``axis_centre`` metadata (JSON string or dict) → {"points": "input" | "cloud" | int, "max_shift": float}, or
    None where absent. Raises ``MetadataError`` when malformed."""
    if text is None or text == "":
        return None
    try:
        d = json.loads(text) if isinstance(text, str) else dict(text)
        points = cloud_points_option("axis_centre", d.get("points", DEFAULT_POINTS))
        shift = d.get("max_shift", DEFAULT_MAX_SHIFT)
        if not _share(shift):
            raise ValueError(f"max_shift must be a share of the body radius in (0, 2], got {shift!r}")
    except (ValueError, TypeError, AttributeError) as e:                       # ConfigError is a ValueError
        raise MetadataError(f"{source}: malformed axis_centre metadata ({e}); write it again with the release "
                            "recipe's [axis_centre] table") from None
    return {"points": points, "max_shift": float(shift)}
