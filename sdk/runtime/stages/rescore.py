"""Stage ``rescore``: ICP re-scoring of the ``k`` best hypotheses (and the copies' consensus) against the predicted
canonical shape, re-ranked by residual (``equipose.runtime.refine``); skipped under the up prior, which fits its own.

Options: ``k`` hypotheses ("auto": the file's ``refine_calibration``; 0 = off), ``iters`` ICP iterations ("auto":
the file's, else 10), ``densify`` (the template gains the midpoints to each point's N nearest neighbours,
``equipose.runtime.template``; "auto": the file's), ``points`` observation points fitted ("all", or the first n of the
FPS-ordered model input: an even subsample). All starts run in one batched ICP.

Convention: model units, learned frame, centred camera frame of the model input; complete models fit both ways.
"""
from __future__ import annotations

import numpy as np

from equipose.core.icp import icp_multi
from equipose.core.metadata import MAX_DENSIFY
from equipose.core.errors import ConfigError
from equipose.runtime.refine import rank_refined
from equipose.runtime.stage import ObjectState, Stage, int_option, register_stage
from equipose.runtime.template import densify_template

__all__ = ["RescoreStage"]


@register_stage
class RescoreStage(Stage):
    name = "rescore"
    after = "copies"
    options = {"k": "auto", "iters": "auto", "densify": "auto", "points": "all"}

    def __init__(self, k: int, iters: int, densify: int, bidirectional: bool, points: int | None = None):
        self.k, self.iters, self.densify, self.bidirectional = k, iters, densify, bidirectional
        self.points = points                                                    # None: every model input point

    @classmethod
    def build(cls, spec, options, context):
        rcal = spec.refine_calibration or {}
        k = options["k"]
        k = rcal.get("k", 0) if isinstance(k, str) and k == "auto" else int_option(
            "refine", k, 0, None, "hypotheses re-scored by ICP")
        iters = options["iters"]
        iters = rcal.get("iters", 10) if iters in ("auto", None) else int_option(
            "refine_iters", iters, 1, None, "ICP iterations per re-scored hypothesis")
        densify = options["densify"]
        if isinstance(densify, str) and densify == "auto":
            densify = rcal.get("densify", 0) if k else 0
        else:
            densify = int_option("densify", densify, 0, MAX_DENSIFY, "neighbours per template point whose midpoints "
                                 "join the ICP template")
            if densify and not k:
                raise ConfigError("densify is part of the ICP re-scoring: it needs refine > 0 (or leave "
                                  "densify='auto')")
        points = options["points"]
        points = None if points == "all" else int_option("rescore points", points, 16, None,
                                                         "observation points fitted, or 'all'")
        return cls(k, iters, densify, not spec.partial, points) if k else None

    def describe(self) -> dict:
        return {"k": self.k, "iters": self.iters, "densify": self.densify, "points": self.points or "all"}

    def run(self, state: ObjectState) -> None:
        if state.up is not None:                                                # the up prior fits its own
            return
        if self.densify:
            state.template = densify_template(state.canonical, self.densify)   # [M', 3]
        s = state.scores
        top = np.argsort(s)[: min(self.k, len(s))]                              # [k] best first
        R0, t0 = state.R[top], state.t[top]
        if state.consensus is not None:                                         # the consensus in the same ICP
            R0 = np.concatenate([R0, state.consensus[0][None]])
            t0 = np.concatenate([t0, state.consensus[1][None]])
        x = state.points if self.points is None else state.points[: self.points]   # FPS prefix: an even subsample
        R, t, res = icp_multi(x, state.template, R0, t0, iters=self.iters,
                              bidirectional=self.bidirectional)
        if state.consensus is not None:
            state.consensus = (R[-1], t[-1], state.consensus[2], float(res[-1]))
            R, t, res = R[:-1], t[:-1], res[:-1]
        state.R[top], state.t[top], state.scores = R, t, rank_refined(s, top, res)
        state.rescored = True
