"""Centre error of the poses ``stand_upright`` turns, against those it leaves, on rendered occluded tabletop views.

    python tools/bench/upright_centre.py --model bowl-tabletop [--views 100] [--seed 1] [--up none|plane]
        [--stages JSON] [--json F]

Every view (``equipose.train.evaluation.confidence.occluded_views``, the category's test shapes, every eighth on its
opening) is predicted with box and mask prompts, without an up prior (``--up plane``: with the support plane's). Among the results whose axis lies within 11° of the
truth on views standing upright, it prints for the turned (``r.extras["rest"] == "upright"``) and the other results:
the count, the median centre error, its median component along the true up (+ = too high) and the share within
2 cm. ``--stages '{"stand_upright": {"height": false}}'`` measures the refit's own centre (v0.42).
Distances in millimetres.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from equipose import PoseEstimator


def main(argv=None) -> int:
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.tabletop import TABLETOP, tabletop_sources
    from equipose.train.evaluation.confidence import handle_parts, occluded_views, view_results

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--views", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--up", choices=("none", "plane"), default="none", help="the up prior of every prediction")
    ap.add_argument("--stages", help="stage options as JSON (PoseEstimator(stages=...))")
    ap.add_argument("--data-root", dest="data_root")
    ap.add_argument("--json", help="write every row here")
    a = ap.parse_args(argv)
    est = PoseEstimator(a.model, stages=json.loads(a.stages) if a.stages else None)
    sources = tabletop_sources(a.data_root or default_data_root(), est.category, "test")
    rows = []
    for v, _, view, rest in occluded_views(sources, a.views, a.seed, False, handle_parts(est, sources),
                                           desc=est.category, upside_down=TABLETOP[est.category].upside_down):
        up = view.R[:, 2]                                                      # [3] the true up (standing views)
        for prompt, _, r, _ in view_results(est, view, ups=(None if a.up == "none" else "plane",)):
            e = np.asarray(r.translation) - view.t                             # [3] m
            rows.append({"view": v, "prompt": prompt, "rest": rest, "turned": r.extras.get("rest") == "upright",
                         "axis_cos": float(r.rotation[:, 2] @ up), "error_mm": float(np.linalg.norm(e)) * 1e3,
                         "vertical_mm": float(e @ up) * 1e3})
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    print(f"{a.model}: {len(rows)} results, seed {a.seed}, up {a.up}")
    for turned in (True, False):
        sel = [r for r in rows if r["turned"] is turned and r["rest"] == "standing" and r["axis_cos"] > 0.98]
        if not sel:
            continue
        err, vert = np.array([r["error_mm"] for r in sel]), np.array([r["vertical_mm"] for r in sel])
        print(f"  {'turned upright' if turned else 'not turned':15s} n {len(sel):4d}  centre error median "
              f"{np.median(err):5.1f} mm  vertical {np.median(vert):+5.1f} mm  within 2 cm {np.mean(err <= 20.0):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
