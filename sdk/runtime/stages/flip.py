"""Stage ``flip`` (metadata ``flip_templates``): front/back (or upside down) settled by fitting category template
shapes from the pose and from its half turns (``equipose.runtime.flip.flip_scores``); under an up prior only the turn
about up. The pose takes the best fit's rotation when a turn wins; ``ambiguous`` says whether the fits decide.
Result extra ``flip_margin``. Options: ``templates`` (how many of the file's, "all"), ``template_points`` (an even
subsample of each, "all"), ``observed_points``, ``iters`` and ``coarse_iters`` of the fits.

Convention: model units, centred camera frame; templates [T, M, 3] category frame.
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import ConfigError
from equipose.core.geometry import farthest_point_order
from equipose.runtime.flip import (FLIP_AMBIGUOUS_MARGIN, FLIP_COARSE_ITERS, FLIP_ICP_ITERS, FLIP_OBSERVED_POINTS,
                                   flip_scores)
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["FlipStage"]


@register_stage
class FlipStage(Stage):
    name = "flip"
    metadata_key = "flip_templates"
    after = "frame_priors"
    options = {"templates": "all", "template_points": "all", "observed_points": FLIP_OBSERVED_POINTS,
               "iters": FLIP_ICP_ITERS, "coarse_iters": FLIP_COARSE_ITERS}

    def __init__(self, templates, axes, partial: bool, observed_points: int = FLIP_OBSERVED_POINTS,
                 iters: int = FLIP_ICP_ITERS, coarse_iters: int = FLIP_COARSE_ITERS):
        self.templates, self.axes, self.partial = np.asarray(templates, np.float64), list(axes), partial
        self.observed_points, self.iters, self.coarse_iters = int(observed_points), int(iters), int(coarse_iters)

    @classmethod
    def build(cls, spec, options, context):
        ft = spec.get(cls.metadata_key)
        if ft is None:
            return None
        T = np.asarray(ft["points"], np.float64)                                # [T, M, 3]
        for key in ("templates", "template_points", "observed_points", "iters", "coarse_iters"):
            v, lowest = options[key], 0 if key == "coarse_iters" else 1
            if key.startswith("template") and v == "all":
                continue
            if isinstance(v, bool) or not isinstance(v, int) or v < lowest:
                raise ConfigError(f"flip option {key} must be an int ≥ {lowest}"
                                  f"{' or all' if key.startswith('template') else ''}, got {v!r}")
        if options["templates"] != "all":
            T = T[: options["templates"]]
        if options["template_points"] != "all" and options["template_points"] < T.shape[1]:
            m = options["template_points"]
            T = np.stack([Ti[farthest_point_order(Ti.astype(np.float32), m)] for Ti in T])   # [T, m, 3]
        return cls(T, ft["axes"], spec.partial, options["observed_points"], options["iters"],
                   min(options["coarse_iters"], options["iters"]))

    def describe(self) -> dict:
        return {"templates": len(self.templates), "template_points": self.templates.shape[1], "axes": self.axes,
                "observed_points": self.observed_points, "iters": self.iters}

    def run(self, state: ObjectState) -> None:
        _, s, R_fit = flip_scores(state.points, state.rotation, state.translation, self.templates, axes=self.axes,
                                  up=state.up, partial=self.partial, observed_points=self.observed_points,
                                  iters=self.iters, coarse_iters=self.coarse_iters)
        order = np.argsort(s, kind="stable")
        margin = float((s[order[1]] - s[order[0]]) / max(s[order[1]], 1e-12)) if len(s) > 1 else 1.0
        if order[0] != 0:                                                       # turned: the template fit's rotation
            state.set_pose(R_fit[order[0]])
        state.ambiguous = margin < FLIP_AMBIGUOUS_MARGIN
        state.extras["flip_margin"] = margin
