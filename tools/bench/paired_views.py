"""Paired comparison of SDK model files on the same rendered partial views (test or training split).

Usage: python tools/bench/paired_views.py --category chair --split train --n 400 A.onnx B.onnx [C.onnx ...]

Each file runs through ``PoseEstimator(file).predict_points`` (its own settings) on the same N evenly spaced views of
the render cache (``data_cache``; rendered on first use). Prints, per file: median rotation error (°), 5° accuracy and
flip rate (> 150°); and, against the first file, the mean per-view change of the error over the views where both are
below 20° (± its standard error) and the share of those views that got better. Symmetric categories are not handled
(plain rotation angle): use it for chair, sofa, car, airplane, laptop.
"""
from __future__ import annotations

import argparse

import numpy as np

from equipose import PoseEstimator
from equipose.core.geometry import rotation_angle_deg
from equipose.train.data.datasets import RenderedPartial
from equipose.train.data.modelnet import default_data_root
from equipose.train.data.render_cache import ensure_cache


def rendered_views(category: str, split: str, n: int = 0, views: int | None = None) -> tuple:
    """``n`` evenly spaced rendered partial views of a ModelNet split (0 = all) → (indices [V] into the render cache,
    ``RenderedPartial.raw`` dicts: ``points_m`` [P, 3] camera frame, metres; ``rotation``, ``translation_m``). ``views`` per instance: default 10
    for train, 5 for test (the render caches the evaluation uses)."""
    views = views or (10 if split == "train" else 5)
    ds = RenderedPartial(ensure_cache(default_data_root(), category, split, views=views), 256, train=False)
    total = len(ds.offsets) - 1
    idx = np.arange(total) if not n else np.linspace(0, total - 1, n).round().astype(int)
    return idx, [ds.raw(int(i)) for i in idx]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--category", required=True)
    ap.add_argument("--split", choices=["train", "test"], default="test")
    ap.add_argument("--n", type=int, default=0, help="views (evenly spaced; 0 = all)")
    ap.add_argument("--views", type=int, default=None, help="rendered views per instance (default: 10 train, 5 test)")
    args = ap.parse_args()
    _, samples = rendered_views(args.category, args.split, args.n, args.views)
    errors = []
    for path in args.models:
        est = PoseEstimator(path, threads=1)
        e = np.array([float(rotation_angle_deg(est.predict_points(s["points_m"]).rotation, s["rotation"]))
                      for s in samples])                                        # [V] degrees
        errors.append(e)
        line = (f"{path}: median {np.median(e):.3f}°  5° {np.mean(e < 5):.3f}  flips {np.mean(e > 150):.3f}"
                f"  n {len(e)}")
        if len(errors) > 1:
            both = (errors[0] < 20) & (e < 20)
            d = (e - errors[0])[both]
            se = d.std(ddof=1) / np.sqrt(len(d))
            line += f"  | vs first, {both.sum()} views < 20°: {d.mean():+.3f} ± {se:.3f}°, better {np.mean(d < 0):.3f}"
        print(line, flush=True)


if __name__ == "__main__":
    main()
