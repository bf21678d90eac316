"""Fit the ``seat`` stage's share: where a standing container's centre sits, per height of its top above the plane.

    python -m equipose.train.evaluation.seat --model sdk/models/cup-tabletop.onnx [--views 150] [--seed 0] [--write]
        [--json F]

Renders the category's standing **training** shapes (point clouds; the test shapes stay for measuring) behind
occluders (``equipose.train.evaluation.confidence.occluded_views``) and predicts each view with box and mask
prompts, without and with ``up="plane"``, the stage reading only (``{"height": "read"}``). Every result posed upright
on the support plane (the stage's reading) gives a row of the true centre's height above the object's base against the
reading's ``top_height``; the median ratio (``equipose.train.evaluation.rest_side.fit_height``) is stored as
``seat`` {"height", "height_rows", "fitted_on"} in the model file and its int8 sibling with ``--write``.

Convention: heights in metres; the object frame's z up, its origin at the centre the pose reports.
"""
from __future__ import annotations

import pathlib
import sys

import numpy as np

from equipose.core.errors import ConfigError
from equipose.train.evaluation.fit_cli import fit_parser
from equipose.train.evaluation.rest_side import report_height

__all__ = ["collect_seat_rows", "main"]


def collect_seat_rows(model, views: int, seed: int, data_root=None, progress: bool = True) -> list:
    """Rows {"view", "prompt", "up", "centre_height" (m: the true centre above the object's base), "top_height" (m:
    the stage's reading)} of the results that pose a standing training shape upright on its support plane."""
    from equipose import PoseEstimator
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.tabletop import TABLETOP, tabletop_sources
    from equipose.train.evaluation.confidence import handle_parts, occluded_views, view_results

    est = PoseEstimator(model, stages={"seat": {"height": "read"}})
    if est.category not in TABLETOP:
        raise ConfigError(f"seat fits tabletop models ({', '.join(TABLETOP)}), not {est.category!r}")
    sources = [src for src in tabletop_sources(data_root or default_data_root(), est.category, "train")
               if "points" in src[1]]                                           # the point-cloud shapes
    rows = []
    for v, s, view, _ in occluded_views(sources, views, seed, False, handle_parts(est, sources),
                                        desc=f"seat {est.category}", progress=progress, upside_down=False):
        base = -float(np.min(np.asarray(sources[s][1]["points"])[:, 2]))      # m: centre above the base, standing
        for prompt, up, r, _ in view_results(est, view, ups=(None, "plane")):
            reading = r.extras.get("seat_reading")
            if reading is not None and reading["top_height"] > 0.0:
                rows.append({"view": v, "prompt": prompt, "up": up or "none", "centre_height": base,
                             "top_height": reading["top_height"]})
    return rows


def main(argv=None) -> int:
    ap = fit_parser(__doc__, views=150)
    a = ap.parse_args(argv)
    rows = collect_seat_rows(a.model, a.views, a.seed, a.data_root)
    fit = report_height(a, pathlib.Path(a.model).name, rows, "posing a standing training shape upright, box and mask, "
                        "with and without up='plane'", "fitted_on")
    if fit is not None and a.write:
        from equipose.export.onnx_export import update_metadata_with_int8
        update_metadata_with_int8(a.model, seat=fit)
    return 0


if __name__ == "__main__":
    sys.exit(main())
