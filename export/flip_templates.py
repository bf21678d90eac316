"""Add front/back templates to an exported model (metadata ``flip_templates``, the SDK's ``equipose.runtime.flip``).

The templates are a teacher network's canonical-shape reconstructions of training clouds of the category (each fed
at a random rotation; the reconstruction is rotation-invariant and is read in the teacher's calibrated category frame),
so no pose label is involved beyond the frame calibration every model has. A self-supervised teacher puts some
instances in a turned frame (airplane-complete: about one in six rolled upside down), so ``pool`` reconstructions are
made and the ``count`` kept are the ones that agree with most others: two shapes agree when their chamfer distance
as they are is below that after a half turn of one about each of ``axes``. Stored in the target model's units (its
``scale``), ``points`` farthest-point samples each.

    python -m equipose.export.flip_templates --model sdk/models/car-partial.onnx --teacher car-complete \
        --category car [--axes z] [--count 6] [--pool 24] [--points 256] [--seed 0]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from scipy.spatial import cKDTree

from equipose.core.errors import InvalidPointsError
from equipose.core.geometry import farthest_point_order, random_rotations
from equipose.runtime.hypotheses import HALF_TURNS

__all__ = ["frame_agreement", "consensus_subset", "teacher_templates", "add_flip_templates", "main"]


def _chamfer(a: np.ndarray, b: np.ndarray, tree_a: cKDTree, tree_b: cKDTree) -> float:
    return float((tree_b.query(a)[0] ** 2).mean() + (tree_a.query(b)[0] ** 2).mean())


def frame_agreement(shapes, axes=("z",)) -> np.ndarray:
    """[S, S] bool: shape j agrees with shape i's frame (chamfer as they are below that after the half turn of j about
    any of ``axes``). Convention: ``shapes`` [S, M, 3] in one frame, one set of units; the diagonal is True."""
    X = np.asarray(shapes, np.float64)
    if X.ndim != 3 or X.shape[2] != 3:
        raise InvalidPointsError(f"shapes must be [S, M, 3] point arrays, got {X.shape}")
    turned = {a: X @ HALF_TURNS[a].T for a in axes}                               # [S, M, 3] each
    trees = [cKDTree(x) for x in X]
    turned_trees = {a: [cKDTree(x) for x in v] for a, v in turned.items()}
    agree = np.eye(len(X), dtype=bool)
    for i in range(len(X)):
        for j in range(len(X)):
            if i != j:
                same = _chamfer(X[i], X[j], trees[i], trees[j])
                agree[i, j] = same < min(_chamfer(X[i], turned[a][j], trees[i], turned_trees[a][j]) for a in axes)
    return agree


def consensus_subset(agree: np.ndarray, count: int) -> np.ndarray:
    """Indices of up to ``count`` shapes in the frame most shapes share: the shape agreeing with the most others is
    the anchor; among those agreeing with it (both ways), the ones agreeing with the most others, best first."""
    votes = agree.sum(1) + agree.sum(0)                                           # [S] agreements given and received
    anchor = int(np.argmax(votes))
    members = np.nonzero(agree[anchor] & agree[:, anchor])[0]                     # the anchor itself included
    return members[np.argsort(-votes[members], kind="stable")][:count]


def teacher_templates(teacher, clouds, count: int = 6, points: int = 256, seed: int = 0, pool: int | None = None,
                      axes=("z",)) -> np.ndarray:
    """[≤ count, points, 3] category-frame reconstructions in metres by ``teacher`` (a ``PoseEstimator``) of clouds
    drawn from ``clouds`` ([S, P, 3] metres, any frame): ``pool`` of them (default ``count``: all kept), then the
    ``consensus_subset`` of their ``frame_agreement`` about ``axes``."""
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(clouds), size=min(max(pool or count, count), len(clouds)), replace=False)
    out = []
    for i, R in zip(pick, random_rotations(len(pick), seed=rng)):
        r = teacher.predict_points(np.asarray(clouds[i], np.float64) @ R.T + [0.0, 0.0, 2.0])
        shape = r.canonical_shape_object                                         # [M, 3] metres, category frame
        out.append(shape[farthest_point_order(shape, min(points, len(shape)))])
    out = np.stack(out)                                                          # [pool, points, 3]
    if len(out) <= count:
        return out
    return out[consensus_subset(frame_agreement(out, axes), count)]


def add_flip_templates(model_path, teacher_model, clouds, *, axes=("z",), count: int = 6, points: int = 256,
                       seed: int = 0, pool: int | None = None, source: str = "") -> np.ndarray:
    """Write ``flip_templates`` into ``model_path`` (its own units). Returns the templates [T, M, 3] model units."""
    from equipose.export.onnx_export import update_metadata
    from equipose.runtime.estimator import PoseEstimator
    target = PoseEstimator(model_path)
    tmpl = teacher_templates(PoseEstimator(teacher_model), clouds, count=count, points=points, seed=seed, pool=pool,
                             axes=axes) / target.scale
    update_metadata(model_path, flip_templates={"points": np.round(tmpl, 5).tolist(), "axes": list(axes),
                                                "source": source})
    return tmpl


def main(argv=None) -> int:
    import os

    from equipose.train.data.modelnet import load_modelnet
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True, help="the .onnx file to update (in place)")
    p.add_argument("--teacher", required=True, help="complete-shape model (name or .onnx) that reconstructs shapes")
    p.add_argument("--category", required=True, help="ModelNet category of the training clouds")
    p.add_argument("--axes", default="z", help="comma-separated category axes whose half turns are checked")
    p.add_argument("--count", type=int, default=6)
    p.add_argument("--pool", type=int, default=None,
                   help="reconstructions made; the --count that agree with most others are kept (default: --count)")
    p.add_argument("--points", type=int, default=256)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data-root", default=os.environ.get("EQUIPOSE_DATA", "../shared/data"))
    a = p.parse_args(argv)
    clouds, _ = load_modelnet(a.data_root, a.category, "train")
    chosen = f"{a.count} of {a.pool} (frame consensus about {a.axes})" if a.pool and a.pool > a.count else a.count
    src = f"{a.teacher} reconstructions of {chosen} ModelNet {a.category} training clouds (seed {a.seed})"
    t = add_flip_templates(a.model, a.teacher, clouds, axes=a.axes.split(","), count=a.count, points=a.points,
                           seed=a.seed, pool=a.pool, source=src)
    print(f"wrote {t.shape[0]} templates × {t.shape[1]} points into {a.model}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
