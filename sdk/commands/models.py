"""``equipose models``: the models shipped with the package (or any given .onnx files) and their metadata."""
from __future__ import annotations

import json

__all__ = ["add_arguments", "run"]


def add_arguments(p):
    p.add_argument("paths", nargs="*", help=".onnx files to describe (default: the bundled models)")
    p.add_argument("--json", action="store_true", help="print JSON")


def run(args) -> int:
    from equipose.estimator import PoseEstimator
    from equipose.models import list_models

    paths = args.paths or list_models()
    rows = []
    for path in paths:
        est = PoseEstimator(path, threads=1)
        info = {"path": str(path), **est.info}
        rows.append(info)
        if not args.json:
            flag = "  RANDOM WEIGHTS (placeholder)" if est.random_init else ""
            print(f"{path}\n  category {est.category}, preset {info['preset']}, {est.num_points} points, scale "
                  f"{est.scale} m/unit, symmetry {est.symmetry}, partial {info['partial']}{flag}")
    if args.json:
        print(json.dumps(rows, indent=1, default=str))
    return 0
