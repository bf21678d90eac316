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

from equipose.train.evaluation.fit_cli import fit_parser
from equipose.train.evaluation.rest_side import collect_heights, report_height

__all__ = ["main"]


def main(argv=None) -> int:
    ap = fit_parser(__doc__, views=150)
    a = ap.parse_args(argv)
    rows = collect_heights(a.model, a.views, a.seed, a.data_root, stage="seat")
    fit = report_height(a, pathlib.Path(a.model).name, rows, "posing a standing training shape upright, box and mask, "
                        "with and without up='plane'", "fitted_on")
    if fit is not None and a.write:
        from equipose.export.onnx_export import update_metadata_with_int8
        update_metadata_with_int8(a.model, seat=fit)
    return 0


if __name__ == "__main__":
    sys.exit(main())
