"""Stage ``cylinder`` (metadata ``shape_prior`` "cylinder"): the symmetry axis of cans and tins from the observed
normals (``equipose.runtime.cylinder.cylinder_axis``), replacing the network's when it fits clearly better.

Convention: model units, centred camera frame; the symmetry axis is the pose's +z column.
"""
from __future__ import annotations

from equipose.core.geometry import rotation_between
from equipose.runtime.cylinder import cylinder_axis
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["CylinderStage"]


@register_stage
class CylinderStage(Stage):
    name = "cylinder"
    metadata_key = "shape_prior"
    after = "turn"

    @classmethod
    def build(cls, spec, options, context):
        return cls() if spec.get(cls.metadata_key) == "cylinder" else None

    def run(self, state: ObjectState) -> None:
        a0 = state.rotation[:, 2]
        a, _, _ = cylinder_axis(state.points, a0)
        state.set_pose(rotation_between(a0, a) @ state.rotation)
