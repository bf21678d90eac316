"""Stage ``polish``: more ICP iterations on the selected pose after re-scoring, on every point of the crop.

Options: ``iters`` ("auto": the file's ``refine_calibration`` polish when its re-scoring runs; 0 = off), ``points``
("cloud": every point of the crop; "input": the model input's N points; n: the crop thinned to at most n points),
``tol`` (0: run ``iters`` updates unless the pairs repeat; t > 0: also stop after the first update that turns the pose
by less than t radians and moves it by less than t model units).

Convention: ICP in the learned frame against the re-scoring's template, then calibrated (model units).
"""
from __future__ import annotations

from equipose.core.icp import icp_multi
from equipose.core.metadata import MAX_POLISH
from equipose.core.geometry import nearest_rotation
from equipose.core.errors import ConfigError
from equipose.runtime.hypotheses import apply_calibration
from equipose.runtime.stage import ObjectState, Stage, cloud_points_option, register_stage

__all__ = ["PolishStage"]


@register_stage
class PolishStage(Stage):
    name = "polish"
    after = "select"
    options = {"iters": "auto", "points": "cloud", "tol": 0.0}

    def __init__(self, iters: int, bidirectional: bool, points: str | int = "cloud", tol: float = 0.0):
        self.iters, self.bidirectional, self.points, self.tol = iters, bidirectional, points, tol

    @classmethod
    def build(cls, spec, options, context):
        rescore = context["built"].get("rescore")
        n = options["iters"]
        if isinstance(n, str) and n == "auto":
            n = (spec.refine_calibration or {}).get("polish", 0) if rescore else 0
        elif isinstance(n, bool) or not isinstance(n, int) or not 0 <= n <= MAX_POLISH:
            raise ConfigError(f"polish must be 'auto' or an int in 0..{MAX_POLISH} (ICP iterations on the selected "
                              f"pose after re-scoring), got {n!r}")
        elif n and rescore is None:
            raise ConfigError("polish is part of the ICP re-scoring (ICP iterations on the selected pose after "
                              "re-scoring): it needs refine > 0 (or leave polish='auto')")
        points = cloud_points_option("polish", options["points"])
        tol = options["tol"]
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0.0 <= tol < 0.1:
            raise ConfigError(f"polish tol must be a number in [0, 0.1) (stop once an ICP update turns the pose by "
                              f"less than tol radians and moves it by less than tol model units; 0: never), "
                              f"got {tol!r}")
        return cls(n, not spec.partial, points, float(tol)) if n else None

    def describe(self) -> dict:
        return {"iters": self.iters, "points": self.points, "tol": self.tol}

    def run(self, state: ObjectState) -> None:
        if not state.rescored or state.selection is None:
            return
        i = state.selection.index
        R_l, t_l = state.learned
        x = state.cloud_points(self.points)                                     # [P', 3]
        Rp, tp, _ = icp_multi(x, state.template, R_l[i][None], t_l[i][None], iters=self.iters,
                              bidirectional=self.bidirectional, tol=self.tol)
        Rp, tp = apply_calibration(Rp, tp, *state.calibration)                  # [1, 3, 3], [1, 3] category frame
        state.R[i], state.t[i] = Rp[0], tp[0]
        state.set_pose(nearest_rotation(Rp[0]), tp[0])
