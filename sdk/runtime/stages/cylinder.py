"""Stage ``cylinder`` (metadata ``shape_prior`` "cylinder" or "open_cylinder"): the symmetry axis of cans and tins
("cylinder"), cups and mugs ("open_cylinder") from the observed normals (``equipose.runtime.cylinder.cylinder_axis``),
replacing the network's when it fits clearly better; for a can without an up prior, only where the category shape
turned onto that axis (re-centred, the axis held) still fits the points within ``SWITCH_FIT_RATIO`` × the pose's
residual: the curved side of a can lying half hidden can follow the standing pattern of side and lid normals, its
outline cannot. A closed cylinder's axis has no sign (its two ends look alike), so where the frame has a support
plane under a can the pose is half-turned about its x axis if needed to keep +z on the plane's side (a standing can
reports upright); an open cylinder keeps the network's sign (a cup may stand on its
rim), and its axis is then refined on the side normals (``refine_side_axis``: the network's axis is the less
precise one for cups and mugs, the more precise one for cans).
With an up prior (``state.up``) the axis is given and the stage leaves the pose, except where a can's normals
clearly say the axis lies ≥ 45° from it: the can lies on its side, its other rest pose. Its axis then becomes the
normals' axis turned level (perpendicular to up), and the result reports ``rest`` "lying" (else "standing") and
``up_contradicted`` True. Extra ``axis_ratio``: the cylinder-pattern cost of the best axis ≥ 45° from the pose's
over the pose's own (below 1: another axis fits the normals better; clipped at 2). Cups and mugs keep the prior's
axis: their tapered sides would turn 0.068 of rendered standing cups onto their side.

Convention: model units, centred camera frame; the symmetry axis is the pose's +z column.
"""
from __future__ import annotations

import numpy as np

from equipose.core.geometry import rotation_between
from equipose.core.icp import icp_multi
from equipose.runtime.cylinder import cylinder_axis, refine_side_axis
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["CylinderStage"]

UP_CONTRADICTION_RATIO = 0.95   # under an up prior: a far axis whose cost is below this × the prior's contradicts it
                                # (rendered cans: 0.970 of lying ones flagged, 0.005 of standing ones)
AXIS_RATIO_CLIP = 2.0       # result extra ``axis_ratio`` (evidence): saturates here
LYING_ICP_ITERS = 8         # ICP steps that re-centre a can turned onto its side (its axis held level)
SWITCH_FIT_RATIO = 8.0      # without an up prior: the normals' axis replaces the pose's only where the shape posed on
                            # it (re-centred, axis held) fits the points within this × the pose's residual


@register_stage
class CylinderStage(Stage):
    name = "cylinder"
    metadata_key = "shape_prior"
    after = "flip_risk"

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
        normals = state.normals()                                               # [N, 3]
        if state.up is not None:                    # the up prior fixes the axis unless the can clearly lies
            a, c0, c_far = cylinder_axis(state.points, a0, normals=normals, ratio=np.inf)   # the best far axis
            contradicted = bool(c_far < UP_CONTRADICTION_RATIO * c0)
            state.extras["up_contradicted"] = contradicted
            ratio = c0 / c_far if contradicted else c_far / c0                  # the other axis's cost / the pose's
            state.extras["axis_ratio"] = float(min(ratio, AXIS_RATIO_CLIP))
            state.extras["rest"] = "lying" if contradicted else "standing"
            if contradicted:
                up = np.asarray(state.up, np.float64)                           # [3] unit, camera frame
                level = a - float(a @ up) * up                                  # [3] the axis turned level
                level /= np.linalg.norm(level)
                R0 = rotation_between(a0, level) @ state.rotation                   # [3, 3]
                R, t, _ = icp_multi(state.points, state.canonical_category, R0[None], state.translation[None],
                                    iters=LYING_ICP_ITERS, hold=(2, level))     # the centre, the axis held level
                state.set_pose(R[0], t[0])
            return
        table = () if state.support_up is None else (state.support_up,)         # standing is a candidate too
        a, c0, c = cylinder_axis(state.points, a0, normals=normals, candidates=table)
        if not self.unsigned:                                                   # a cup or a mug
            a = refine_side_axis(normals, a)
        R = rotation_between(a0, a) @ state.rotation                            # [3, 3]
        if self.unsigned and c < c0 and not self._fits(state, R):              # the normals' far axis won
            return                                                              # the shape says otherwise
        if self.unsigned and state.support_up is not None and float(R[:, 2] @ state.support_up) < 0.0:
            R = R @ np.diag([1.0, -1.0, -1.0])                                  # the other end up
        state.set_pose(R)

    @staticmethod
    def _fits(state: ObjectState, R: np.ndarray) -> bool:
        """Whether the category shape turned onto the normals' axis (``R`` [3, 3]) and re-centred with that axis held
        (``LYING_ICP_ITERS`` steps) fits the points within ``SWITCH_FIT_RATIO`` × the pose's own residual: the side
        normals of a can lying half hidden can follow the standing pattern, its outline cannot."""
        shape, x = state.canonical_category, state.points
        _, _, own = icp_multi(x, shape, state.rotation[None], state.translation[None], iters=0)
        _, _, turned = icp_multi(x, shape, R[None], state.translation[None], iters=LYING_ICP_ITERS,
                                 hold=(2, R[:, 2]))
        return bool(turned[0] <= SWITCH_FIT_RATIO * own[0])
