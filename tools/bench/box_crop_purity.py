"""What a box crop keeps on rendered occluded tabletop views: the object, or what stands in front of it?

Usage: python tools/bench/box_crop_purity.py [--models mug cup can bowl] [--views 200] [--seed 1] [--json FILE]
Each view is ``equipose.train.data.occluded.render_occluded`` (a test shape on a table, an occluder panel in front
with probability 0.7, the sensor model) with the view's visible-mask box as the prompt. Per category: the share of
box crops with more than 5 / 10 / 20 % of their points off the object's visible mask, and the object points the box
crop keeps against the mask crop's point count (median, 10th percentile). The counts depend on the crop's lattice
pitch, which a larger region coarsens, so the second figure can sit near 0.25 for a crop that lost nothing.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys

import numpy as np

from equipose import PoseEstimator
from equipose.core.errors import EquiposeError


def purity(category: str, views: int, seed: int) -> dict:
    """{"n", "off_05", "off_10", "off_20", "kept_median", "kept_p10", "off_views"} of ``category``'s box crops."""
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.occluded import render_occluded
    from equipose.train.data.tabletop import tabletop_sources

    est = PoseEstimator(f"{category}-tabletop")
    sources = tabletop_sources(default_data_root(), category, "test")
    off, kept, names = [], [], []
    for v in range(views):
        s = v % len(sources)
        view = render_occluded(sources[s][1], np.random.default_rng([seed, v]))
        if view is None:
            continue
        try:
            by_box = est.crop(view.depth, view.K, depth_unit="mm", box=view.box)
            by_mask = est.crop(view.depth, view.K, depth_unit="mm", mask=view.mask)
        except EquiposeError:
            continue
        on = view.mask[by_box.pixels[:, 0], by_box.pixels[:, 1]]               # [P] box crop points on the object
        off.append(1.0 - float(on.mean()))
        kept.append(float(on.sum()) / max(len(by_mask.points), 1))
        if off[-1] > 0.1:
            names.append(f"{s}:{v}")
    off_a = np.array(off)
    return {"n": len(off), "off_05": float(np.mean(off_a > 0.05)), "off_10": float(np.mean(off_a > 0.1)),
            "off_20": float(np.mean(off_a > 0.2)), "kept_median": float(np.median(kept)),
            "kept_p10": float(np.percentile(kept, 10)), "off_views": names}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=["mug", "cup", "can", "bowl"], help="tabletop categories")
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--json", help="write the figures here")
    a = ap.parse_args(argv)
    out = {}
    print(f"{'category':10s} {'views':>5s} {'>5% off':>8s} {'>10% off':>9s} {'>20% off':>9s} "
          f"{'kept med':>9s} {'kept p10':>9s}  views > 10 % off (shape:view)")
    for c in a.models:
        r = out[c] = purity(c, a.views, a.seed)
        print(f"{c:10s} {r['n']:5d} {r['off_05']:8.3f} {r['off_10']:9.3f} {r['off_20']:9.3f} {r['kept_median']:9.3f} "
              f"{r['kept_p10']:9.3f}  {' '.join(r['off_views'])}")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
