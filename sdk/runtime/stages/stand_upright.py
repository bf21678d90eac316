"""Stage ``stand_upright`` (metadata ``upright_rest``): without an up prior, an open container posed on its opening is
stood upright where the end facing up reads open.

A pose that stands a cup, mug or bowl on its opening on the support plane under it (its category up axis z pointing
into the table) claims that the closed base faces up. Where ``equipose.core.opening.top_closure`` finds the end facing
up open instead (its ``bottom`` share, the points near the axis at the posed bottom, below the file's ``cap``), the
view contradicts the pose: an upright container posed upside down, the network's most common error on them. The stage
turns the pose over (a half turn about the category x axis) and refits its azimuth and centre with the axis held on the
support plane's normal (``equipose.runtime.upright.upright_icp``).

The refit finds the azimuth, but not the height: the network's canonical shape was decoded for the pose it chose,
and turned over it can sit centimetres too high (docs/results/real/README.md, v0.43). Where the file holds a
``height`` h, the centre is set instead to h × the height of the object's top above the plane (the 95th percentile
of its crop points' heights): a container's centre sits at a share of its height that varies little within a
category.

``upright_rest`` JSON {"cap": c, "height": h, ...} holds c, chosen on rendered views where the turn fixes at least ten
times as many results as it breaks (``equipose.train.evaluation.rest_side --upright``), and h, the median share on
rendered training shapes (``... --upright --height``). Options: ``cap``: "auto" (the file's; absent: the stage does
not run), a share in (0, 1], or "read" (report the reading, never turn); ``height``: "auto" (the file's; absent: the
refit's centre), a share in (0, 1], or False (the refit's centre). Result extras where it reads: ``upright_reading``
{"bottom_cap": the share, "top_taper": how much the body widens towards the end on the table, "top_height": the
object's top above the plane, metres}, and ``rest`` "upright" where it turned the pose. Under an up prior the stage
does nothing (the prior holds the axis; stage ``rest_side`` decides there).

Convention: category frame, model units, centred camera frame; the support plane's normal a unit camera-frame
direction.
"""
from __future__ import annotations

from equipose.core.errors import ConfigError, MetadataError
from equipose.core.geometry import nearest_rotation
from equipose.runtime.stage import ObjectState, ShareCapStage, is_share, register_stage
from equipose.runtime.stages.rest_side import HALF_TURN_X
from equipose.runtime.upright import upright_icp

__all__ = ["StandUprightStage", "parse_upright_rest"]


@register_stage
class StandUprightStage(ShareCapStage):
    name = "stand_upright"
    metadata_key = "upright_rest"
    fit_command = "python -m equipose.train.evaluation.rest_side --upright --model ... --write"
    after = "rest_side"
    options = {"cap": "auto", "height": "auto"}

    def __init__(self, cap: float | None, height: float | None = None):
        super().__init__(cap)
        self.height = height                                                    # None: the refit's centre

    @classmethod
    def parse(cls, text, source: str = "model") -> dict | None:
        """``upright_rest`` metadata → {"cap": share, "height": share (when fitted), ...} or None. Raises
        ``MetadataError`` when malformed."""
        d = super().parse(text, source)
        if d is not None and "height" in d:
            h = d["height"]
            if not is_share(h):
                raise MetadataError(f"{source}: upright_rest height must be a share in (0, 1], got {h!r}; re-run "
                                    f"'{cls.fit_command.replace('--write', '--height --write')}'")
            d["height"] = float(h)
        return d

    @classmethod
    def build(cls, spec, options, context):
        stage = super().build(spec, {"cap": options["cap"]}, context)
        height = options.get("height", "auto")
        if stage is None or stage.cap is None or height is False:
            return stage
        if isinstance(height, str) and height == "auto":
            stage.height = (cls.parse(spec.get(cls.metadata_key), spec.name) or {}).get("height")
        elif not is_share(height):
            raise ConfigError(f"stand_upright height must be 'auto', False or a share in (0, 1] (the centre's height "
                              f"above the support plane per height of the object's top), got {height!r}")
        else:
            stage.height = float(height)
        return stage

    def describe(self) -> dict:
        return {**super().describe(), "height": self.height}

    def run(self, state: ObjectState) -> None:
        if state.up is not None or state.support_up is None or state.rotation is None:
            return
        axis = state.rotation[:, 2]                                             # [3] the pose's category up
        if float(axis @ state.support_up) >= 0.0:                               # not posed on its opening
            return
        ends = state.closure()                                                  # the end facing up: ends.bottom
        top = state.top_height()                                                # m above the plane
        state.extras["upright_reading"] = {"bottom_cap": ends.bottom, "top_taper": ends.taper, "top_height": top}
        if self.cap is None or ends.bottom >= self.cap:
            return
        R, t, _ = upright_icp(state.points, state.canonical_category, (state.rotation @ HALF_TURN_X)[None],
                              state.translation[None], state.support_up)       # stood on its base, refitted
        t = t[0] if self.height is None else state.at_height(t[0], self.height * top)   # [3] model units
        state.set_pose(nearest_rotation(R[0]), t)
        state.extras["rest"] = "upright"


parse_upright_rest = StandUprightStage.parse     # ``upright_rest`` metadata → {"cap": share, ...} or None
