"""Add front/back templates to an exported model (metadata ``flip_templates``, the SDK's ``equipose.runtime.flip``).

The templates are a teacher network's canonical-shape reconstructions of ``count`` training clouds of the category
(each fed at a random rotation; the reconstruction is rotation-invariant and is read in the teacher's calibrated
category frame), so no pose label is involved beyond the frame calibration every model has. Stored in the target
model's units (its ``scale``), ``points`` farthest-point samples each.

    python -m equipose.export.flip_templates --model sdk/models/car-partial.onnx --teacher car-complete \
        --category car [--axes z] [--count 6] [--points 256] [--seed 0]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from equipose.core.geometry import farthest_point_order, random_rotations

__all__ = ["teacher_templates", "add_flip_templates", "main"]


def teacher_templates(teacher, clouds, count: int = 6, points: int = 256, seed: int = 0) -> np.ndarray:
    """[count, points, 3] category-frame reconstructions in metres by ``teacher`` (a ``PoseEstimator``) of ``count``
    clouds drawn from ``clouds`` ([S, P, 3] metres, any frame)."""
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(clouds), size=min(count, len(clouds)), replace=False)
    out = []
    for i, R in zip(pick, random_rotations(len(pick), seed=rng)):
        r = teacher.predict_points(np.asarray(clouds[i], np.float64) @ R.T + [0.0, 0.0, 2.0])
        shape = r.canonical_shape_object                                         # [M, 3] metres, category frame
        out.append(shape[farthest_point_order(shape, min(points, len(shape)))])
    return np.stack(out)


def add_flip_templates(model_path, teacher_model, clouds, *, axes=("z",), count: int = 6, points: int = 256,
                       seed: int = 0, source: str = "") -> np.ndarray:
    """Write ``flip_templates`` into ``model_path`` (its own units). Returns the templates [T, M, 3] model units."""
    from equipose.export.onnx_export import update_metadata
    from equipose.runtime.estimator import PoseEstimator
    target = PoseEstimator(model_path)
    tmpl = teacher_templates(PoseEstimator(teacher_model), clouds, count=count, points=points, seed=seed) / target.scale
    update_metadata(model_path, flip_templates={"points": np.round(tmpl, 5).tolist(), "axes": list(axes),
                                                "source": source})
    return tmpl


def main(argv=None) -> int:
    import os

    from equipose.train.modelnet import load_modelnet
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True, help="the .onnx file to update (in place)")
    p.add_argument("--teacher", required=True, help="complete-shape model (name or .onnx) that reconstructs shapes")
    p.add_argument("--category", required=True, help="ModelNet category of the training clouds")
    p.add_argument("--axes", default="z", help="comma-separated category axes whose half turns are checked")
    p.add_argument("--count", type=int, default=6)
    p.add_argument("--points", type=int, default=256)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data-root", default=os.environ.get("EQUIPOSE_DATA", "../shared/data"))
    a = p.parse_args(argv)
    clouds, _ = load_modelnet(a.data_root, a.category, "train")
    src = f"{a.teacher} reconstructions of {a.count} ModelNet {a.category} training clouds (seed {a.seed})"
    t = add_flip_templates(a.model, a.teacher, clouds, axes=a.axes.split(","), count=a.count, points=a.points, seed=a.seed, source=src)
    print(f"wrote {t.shape[0]} templates × {t.shape[1]} points into {a.model}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
