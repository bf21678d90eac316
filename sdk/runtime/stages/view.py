"""Stage ``view``: view-aware re-scoring of partial views (``equipose.runtime.visibility``): the re-scored poses are
also charged for template parts the camera would see but the view lacks; the copies' vote weighs in.

Options: ``exponent`` of the hidden-point removal ("auto": the file's ``refine_calibration`` visibility when its
re-scoring runs; None = off); ``k`` the best re-scored poses it ranks ("auto": all of them, the re-scoring's ``k``
plus the copies' consensus). Runs only after stage ``rescore`` ran on the object.

Convention: model units, learned frame, centred camera frame (the camera at ``−centre_m / scale``).
"""
from __future__ import annotations

from equipose.core.errors import ConfigError
from equipose.runtime.stage import ObjectState, Stage, int_option, register_stage
from equipose.runtime.visibility import VIEW_AMBIGUOUS_MARGIN, view_rescore

__all__ = ["ViewStage"]


@register_stage
class ViewStage(Stage):
    name = "view"
    after = "consensus"
    options = {"exponent": "auto", "k": "auto"}

    def __init__(self, exponent: float, k: int):
        self.exponent, self.k = float(exponent), int(k)

    @classmethod
    def build(cls, spec, options, context):
        rescore = context["built"].get("rescore")
        e = options["exponent"]
        if isinstance(e, str) and e == "auto":
            e = (spec.refine_calibration or {}).get("visibility") if (rescore and spec.partial) else None
        elif e is not None:
            if isinstance(e, (bool, str)) or not isinstance(e, (int, float)) or not -3 <= e <= 6:
                raise ConfigError(f"visibility must be 'auto', None or an exponent in -3..6 (view-aware re-scoring, "
                                  f"equipose.runtime.visibility), got {e!r}")
            if not spec.partial:
                raise ConfigError(f"visibility (view-aware re-scoring) applies to partial-view models; {spec.name} is "
                                  "a complete-shape model: leave visibility='auto' or None")
        if e is None or rescore is None:
            return None
        k = rescore.k + ("copies" in context["built"])
        if options["k"] != "auto":
            k = int_option("view k", options["k"], 1, None, "best re-scored poses ranked by the view-aware residual")
        return cls(e, k)

    def describe(self) -> dict:
        return {"exponent": self.exponent, "k": self.k}

    def run(self, state: ObjectState) -> None:
        if not state.rescored:
            return
        copy_poses = None if state.copy_poses is None else state.copy_poses[0]  # [K, 3, 3]
        state.scores = view_rescore(state.prep, state.canonical, state.R, state.t, state.scores, k=self.k,
                                    symmetry=state.symmetry, exponent=self.exponent, copy_poses=copy_poses)
        state.view_scored = True
        state.ambiguous_margin = VIEW_AMBIGUOUS_MARGIN
