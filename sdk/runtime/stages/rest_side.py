"""Stage ``rest_side`` (metadata ``upside_down_rest``): an open container under the up prior stood on its opening where
both the network and the view say so.

The up prior (stage ``upright``) holds the pose's axis on "up", the opening upwards: a bowl standing on its rim comes
out upright, 180° off. This stage turns the pose over (a half turn about the category x axis) and refits its azimuth
and centre with the axis held on "down" (``equipose.runtime.upright.upright_icp``) where two independent readings
agree that it stands the other way up:
- the network's own best hypothesis (lowest score, before the prior) has its up axis pointing down (cos < 0), and
- the upright pose's top reads closed: ``equipose.core.opening.top_closure``'s ``cap`` reaches the file's ``cap``.

``upside_down_rest`` JSON {"cap": c, ...} holds c, chosen on rendered views where the turn fixes at least ten times as
many results as it breaks (``equipose.train.evaluation.rest_side``). Option ``cap``: "auto" (the file's; absent: the
stage does not run), a share in (0, 1], or "read" (report the readings, never turn: what the fit collects). Result
extras under a prior: ``rest_reading`` {"own_up": cos of the network's own axis with up, "top_cap": the upright
pose's closed-top share}, and ``rest`` "upside_down" where it turned the pose.

Convention: category frame, model units, centred camera frame; ``up`` a unit camera-frame direction.
"""
from __future__ import annotations

import math

import numpy as np

from equipose.core.errors import ConfigError, MetadataError
from equipose.core.geometry import nearest_rotation
from equipose.core.metadata import float_entry
from equipose.core.opening import top_closure
from equipose.runtime.stage import ObjectState, Stage, register_stage
from equipose.runtime.upright import upright_icp

__all__ = ["RestSideStage", "ShareCapStage", "parse_upside_down_rest", "parse_share_cap", "HALF_TURN_X"]

HALF_TURN_X = np.diag([1.0, -1.0, -1.0])       # category frame: the opening (+z) turned down, x kept


def parse_share_cap(text, name: str, source: str, hint: str) -> dict | None:
    """A ``{"cap": share, ...}`` metadata entry ``name`` (JSON string or dict) → the dict with ``cap`` a float in
    (0, 1], or None when absent. Raises ``MetadataError`` naming the command that writes it (``hint``) when malformed."""
    d = float_entry(text, name, "cap", source, hint)
    if d is not None and not (math.isfinite(d["cap"]) and 0.0 < d["cap"] <= 1.0):
        raise MetadataError(f"{source}: {name} cap must be a share in (0, 1], got {d['cap']}")
    return d


def parse_upside_down_rest(text, source: str = "model") -> dict | None:
    """``upside_down_rest`` metadata → the dict with ``cap`` a float in (0, 1], or None (``parse_share_cap``)."""
    return parse_share_cap(text, "upside_down_rest", source,
                           "python -m equipose.train.evaluation.rest_side --model ... --write")


class ShareCapStage(Stage):
    """A stage that acts where a reading passes its model file's share threshold ``cap`` (``parse``) and otherwise
    only reports the reading. Option ``cap``: "auto" (the file's; absent: the stage does not run), a share in (0, 1],
    or "read" (``cap`` None: report, never act)."""
    options = {"cap": "auto"}

    def __init__(self, cap: float | None):
        self.cap = cap                                                          # None: read only

    @classmethod
    def parse(cls, text, source: str) -> dict | None:
        raise NotImplementedError

    @classmethod
    def build(cls, spec, options, context):
        cap = options["cap"]
        if isinstance(cap, str) and cap == "auto":
            d = cls.parse(spec.get(cls.metadata_key), spec.name)
            return None if d is None else cls(d["cap"])
        if isinstance(cap, str) and cap == "read":
            return cls(None)
        if isinstance(cap, bool) or not isinstance(cap, (int, float)) or not 0.0 < cap <= 1.0:
            raise ConfigError(f"{cls.name} cap must be 'auto', 'read' or a share in (0, 1], got {cap!r}")
        return cls(float(cap))

    def describe(self) -> dict:
        return {"cap": self.cap if self.cap is not None else "read"}


@register_stage
class RestSideStage(ShareCapStage):
    name = "rest_side"
    metadata_key = "upside_down_rest"
    after = "cylinder"

    @classmethod
    def parse(cls, text, source: str) -> dict | None:
        return parse_upside_down_rest(text, source)

    def run(self, state: ObjectState) -> None:
        if state.up is None or state.rotation is None:
            return
        own = state.R[int(np.argmin(state.scores))]                            # [3, 3] the network's best, no prior
        own_up = float(own[:, 2] @ state.up)
        cap = top_closure(state.points, state.rotation[:, 2], state.translation).cap
        state.extras["rest_reading"] = {"own_up": own_up, "top_cap": cap}
        if self.cap is None or own_up >= 0.0 or cap < self.cap:
            return
        R, t, _ = upright_icp(state.points, state.canonical_category, (state.rotation @ HALF_TURN_X)[None],
                              state.translation[None], -state.up)              # stood on its opening, refitted
        state.set_pose(nearest_rotation(R[0]), t[0])
        state.extras["rest"] = "upside_down"
