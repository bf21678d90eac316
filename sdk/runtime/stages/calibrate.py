"""Stage ``calibrate``: hypotheses and canonical shape from the network's learned frame into the category frame.

The calibration is the file's ``refine_calibration`` when stage ``rescore`` is configured (it was measured on
re-scored poses), else its plain ``calibration_rotation`` / ``calibration_translation``. The learned-frame
hypotheses stay in ``state.learned`` for stages that fit in that frame (``polish``).

Convention: ``R_cat = R · δRᵀ``, ``t_cat = t − R_cat · δt`` (model units); shape ``y_cat = δR y + δt``.
"""
from __future__ import annotations

import numpy as np

from equipose.runtime.hypotheses import apply_calibration
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["CalibrateStage"]


@register_stage
class CalibrateStage(Stage):
    name = "calibrate"
    after = "view"

    def __init__(self, rotation, translation):
        self.rotation = np.asarray(rotation, np.float64)                       # [3, 3] δR
        self.translation = np.asarray(translation, np.float64)                 # [3] δt, model units

    @classmethod
    def build(cls, spec, options, context):
        if context.get("calibration") is not None:                             # set on the estimator
            return cls(*context["calibration"])
        rcal = spec.refine_calibration
        if "rescore" in context["built"] and rcal:
            return cls(rcal["rotation"], rcal["translation"])
        return cls(*spec.calibration)

    def run(self, state: ObjectState) -> None:
        state.learned = (state.R, state.t)
        state.R, state.t = apply_calibration(state.R, state.t, self.rotation, self.translation)  # [A, 3, 3], [A, 3]
        state.canonical_category = state.canonical @ self.rotation.T + self.translation       # [M, 3]
        state.calibration = (self.rotation, self.translation)
        state.calibrated = True
