"""Stage ``cylinder`` (metadata ``shape_prior`` "cylinder" or "open_cylinder"): the symmetry axis of cans and tins
("cylinder"), cups and mugs ("open_cylinder") from the observed normals (``equipose.runtime.cylinder.cylinder_axis``),
replacing the network's when it fits clearly better. A closed cylinder's axis has no sign (its two ends look alike),
so where the frame has a support plane under a can the pose is half-turned about its x axis if needed to keep +z on
the plane's side (a standing can reports upright); an open cylinder keeps the network's sign (a cup may stand on its
rim), and its axis is then refined on the side normals (``refine_side_axis``: the network's axis is the less
precise one for cups and mugs, the more precise one for cans).
With an up prior (``state.up``) the axis is given and the stage leaves the pose, but where a can's normals clearly
say the axis lies ≥ 45° from it (lying on its side while the prior says it stands) the result is flagged
``ambiguous`` (result extra ``up_contradicted``; not for cups and mugs, whose tapered sides flagged 0.068 of rendered
standing cups).

Convention: model units, centred camera frame; the symmetry axis is the pose's +z column.
"""
from __future__ import annotations

import numpy as np

from equipose.core.geometry import rotation_between
from equipose.core.normals import point_normals
from equipose.runtime.cylinder import SWITCH_ANGLE_DEG, cylinder_axis, refine_side_axis
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["CylinderStage"]

NORMAL_NEIGHBOURS = 12      # points per PCA normal
UP_CONTRADICTION_RATIO = 0.95   # under an up prior: a far axis whose cost is below this × the prior's contradicts it
                                # (rendered cans: 0.970 of lying ones flagged, 0.005 of standing ones)


@register_stage
class CylinderStage(Stage):
    name = "cylinder"
    metadata_key = "shape_prior"
    after = "turn"

    def __init__(self, unsigned: bool = True):
        self.unsigned = bool(unsigned)                                          # the axis has no sign (a can)

    @classmethod
    def build(cls, spec, options, context):
        prior = spec.get(cls.metadata_key)
        return cls(unsigned=prior == "cylinder") if prior in ("cylinder", "open_cylinder") else None

    def describe(self) -> dict:
        return {"unsigned": self.unsigned}

    def run(self, state: ObjectState) -> None:
        if state.up is not None and not self.unsigned:                          # the up prior fixes a cup's axis
            return
        a0 = state.rotation[:, 2]
        normals = point_normals(state.points, NORMAL_NEIGHBOURS)                # [N, 3]
        if state.up is not None:                    # the up prior fixes the axis; a view that contradicts it is flagged
            a, _, _ = cylinder_axis(state.points, a0, normals=normals, ratio=UP_CONTRADICTION_RATIO)
            contradicted = bool(abs(float(a @ a0)) < np.cos(np.radians(SWITCH_ANGLE_DEG)))
            state.extras["up_contradicted"] = contradicted
            state.ambiguous = bool(state.ambiguous or contradicted)
            return
        table = () if state.support_up is None else (state.support_up,)         # standing is a candidate too
        a, _, _ = cylinder_axis(state.points, a0, normals=normals, candidates=table)
        if not self.unsigned:                                                   # a cup or a mug
            a = refine_side_axis(normals, a)
        R = rotation_between(a0, a) @ state.rotation                            # [3, 3]
        if self.unsigned and state.support_up is not None and float(R[:, 2] @ state.support_up) < 0.0:
            R = R @ np.diag([1.0, -1.0, -1.0])                                  # the other end up
        state.set_pose(R)
