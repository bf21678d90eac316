"""Stage ``rim_axis`` (metadata ``rim_axis``; partial models of open containers with symmetry ``continuous:z``): the
pose's symmetry axis turned onto the normal of the plane of the container's rim (``equipose.core.rim.rim_axis``).

A bowl's side is close to a sphere, whose normals do not fix an axis (the ``cylinder`` stage's reading), and the
network reads a partial bowl's axis several degrees off (docs/results/real/README.md, v0.49). The rim and the upper wall seen from above form a ring band whose plane
fixes the axis by geometry alone. The pose is turned by the smallest rotation taking its axis onto the fitted one
(the azimuth of a symmetric body does not matter; the centre stays, for ``axis_centre`` to move across the new axis).
A fit that the band refuses (too few points, not a ring) or that would turn the axis by more than ``max_turn``
degrees leaves the pose as it is. Under an up prior the stage does nothing: the prior holds the axis. Result extra
``rim_turn_deg``: how far the axis turned (None where the stage left it).

It changes the poses a model's centre and confidence calibrations are fitted on, so it runs where the file says
(metadata ``rim_axis`` JSON {"band": ..., "max_turn": ..., "points": ...}, written by the release recipe's
``[rim_axis]`` table before those fits) or where asked: ``stages={"rim_axis": {"enabled": True}}``.

Options: ``enabled``: "auto" (the file's entry present), True or False; ``band``: "auto" (the file's, else
``RIM_BAND``) or a share in (0, 1); ``max_turn``: "auto" (the file's, else 30) or degrees in (0, 90];
``points``: "auto" (the file's, else "cloud"), "cloud", "input" or an int (``cloud_points_option``). Runs after
``stand_upright`` (which way up is settled) and before ``axis_centre``.

Convention: model units, centred camera frame; the symmetry axis is the pose's +z column, out of the opening.
"""
from __future__ import annotations

import json

from equipose.core.errors import ConfigError, MetadataError
from equipose.core.geometry import rotation_between
from equipose.core.rim import RIM_BAND, rim_axis
from equipose.runtime.stage import (ObjectState, Stage, cloud_points_option, enabled_option,
                                    entry_options, register_stage)

__all__ = ["RimAxisStage", "parse_rim_axis", "DEFAULT_MAX_TURN", "DEFAULT_POINTS"]

DEFAULT_MAX_TURN = 30.0         # degrees: a larger turn is not a correction of the network's axis but another reading
DEFAULT_POINTS = "cloud"        # the crop's points: the band needs more than the model input's few hundred


@register_stage
class RimAxisStage(Stage):
    name = "rim_axis"
    metadata_key = "rim_axis"
    after = "stand_upright"
    options = {"enabled": "auto", "band": "auto", "max_turn": "auto", "points": "auto"}

    def __init__(self, band: float = RIM_BAND, max_turn: float = DEFAULT_MAX_TURN, points=DEFAULT_POINTS):
        self.band = float(band)
        self.max_turn = float(max_turn)
        self.points = points

    @classmethod
    def build(cls, spec, options, context):
        if not spec.partial or spec.symmetry != "continuous:z":
            return None
        entry = parse_rim_axis(spec.get(cls.metadata_key), spec.name)
        if not enabled_option(cls.name, options["enabled"], entry):
            return None
        chosen = entry_options(options, entry or {"band": RIM_BAND, "max_turn": DEFAULT_MAX_TURN,
                                                  "points": DEFAULT_POINTS})
        band, turn, points = chosen["band"], chosen["max_turn"], chosen["points"]
        if not _band(band):
            raise ConfigError(f"rim_axis band must be 'auto' or a share in (0, 1), got {band!r}")
        if not _turn(turn):
            raise ConfigError(f"rim_axis max_turn must be 'auto' or degrees in (0, 90], got {turn!r}")
        return cls(float(band), float(turn), cloud_points_option(cls.name, points))

    def describe(self) -> dict:
        return {"band": self.band, "max_turn": self.max_turn, "points": self.points}

    def run(self, state: ObjectState) -> None:
        state.extras["rim_turn_deg"] = None
        if state.rotation is None or state.up is not None:
            return
        axis = state.rotation[:, 2]                                             # [3] centred camera frame
        fit = rim_axis(state.cloud_points(self.points), axis, self.band)
        if fit is None or fit.turn > self.max_turn:
            return
        state.set_pose(rotation_between(axis, fit.axis) @ state.rotation)
        state.extras["rim_turn_deg"] = fit.turn


def _band(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 < v < 1.0


def _turn(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 < v <= 90.0


def parse_rim_axis(text, source: str = "model") -> dict | None:
    """``rim_axis`` metadata (JSON string or dict) → {"band": share, "max_turn": degrees, "points": "cloud" | "input" |
    int}, or None where absent. Raises ``MetadataError`` when malformed."""
    if text is None or text == "":
        return None
    try:
        d = json.loads(text) if isinstance(text, str) else dict(text)
        band, turn = d.get("band", RIM_BAND), d.get("max_turn", DEFAULT_MAX_TURN)
        points = cloud_points_option("rim_axis", d.get("points", DEFAULT_POINTS))
        if not _band(band):
            raise ValueError(f"band must be a share in (0, 1), got {band!r}")
        if not _turn(turn):
            raise ValueError(f"max_turn must be degrees in (0, 90], got {turn!r}")
    except (ValueError, TypeError, AttributeError) as e:                       # ConfigError is a ValueError
        raise MetadataError(f"{source}: malformed rim_axis metadata ({e}); write it again with the release "
                            "recipe's [rim_axis] table") from None
    return {"band": float(band), "max_turn": float(turn), "points": points}
