"""How much of a partial model's rotation error is its template's, and how much its selection's?

Usage: python tools/bench/pipeline_ceiling.py --model sdk/models/chair-partial.onnx --category chair
                                              [--split test|train] [--n N] [--iters K] [--json out.json]

For each rendered view the SDK runs as it ships (``PoseEstimator(model).predict_points``). Then ICP of the view onto
the same result's canonical shape (``PoseResult.canonical_shape_object``, category frame, metres; densified as the
file's ``densify`` does) **starts from the ground-truth pose**, for ``--iters`` iterations (default: the file's
re-scoring plus polish iterations). Where that fit settles is the best pose this template can give (a pose label is
used, so it is a ceiling to compare against, not a method): if it lands more than 5° from the truth, no choice among
hypotheses could have done better; if it lands within 5° while the SDK's pose did not, the SDK chose or converged
in the wrong place. Prints both, and splits the SDK's misses (≥ 5°) into

* ``template``: the ceiling misses too (the predicted shape, not the search, sets the error);
* ``near miss``: ceiling < 5°, SDK within 5–20° (the right basin, settled off);
* ``wrong basin``: ceiling < 5°, SDK ≥ 20° (a flip or another wrong hypothesis won).

Symmetric categories are not handled (plain rotation angle): use it for chair, sofa, car, airplane.

Measured (2026-11-25, 500 test views, v0.19 files; median ° / 5° accuracy):

| model (views) | SDK | template ceiling | SDK misses (≥ 5°): template / near miss / wrong basin |
|---|---|---|---|
| chair-partial (500 test) | 3.83 / 0.612 | 3.47 / 0.678 | 194: 153 / 23 / 18 |
| chair-partial (600 training) | 3.45 / 0.670 | 3.18 / 0.722 | 198: 162 / 24 / 12 |
| sofa-partial (500 test) | 6.45 / 0.420 | 3.92 / 0.616 | 290: 187 / 52 / 51 |
| airplane-partial (500 test) | 2.59 / 0.690 | 2.68 / 0.726 | 155: 122 / 14 / 19 |
| car-partial (500 test) | 6.34 / 0.424 | 3.37 / 0.682 | 288: 146 / 65 / 77 |

Chair is template-bound: four of five misses would miss from the true pose too. The same fit onto the view's true
complete cloud (1,024 points, ground-truth frame) settles at 0.51° / 1.00 (250 test views), so ICP on one view is
not what limits it; onto the complete-shape teacher's reconstruction of the same chair (from its complete cloud)
4.28° / 0.568, against 3.42° / 0.700 for the student's own shape on those views.
"""
from __future__ import annotations

import argparse
import json

import numpy as np

from equipose import PoseEstimator
from equipose.core.geometry import farthest_point_order, rotation_angle_deg
from equipose.runtime.refine import icp_multi
from equipose.runtime.template import densify_template
from paired_views import rendered_views     # tools/bench: the same evenly spaced rendered views

OBSERVED_POINTS = 2048      # the view's points used in the ceiling fit (farthest-point sample), as the SDK's polish


def ceiling_error(est, result, points_m: np.ndarray, R_gt: np.ndarray, t_gt: np.ndarray, iters: int) -> float:
    """Degrees between the truth and where ICP of the view onto ``result``'s canonical shape settles from the truth.

    Convention: ``points_m`` [P, 3] camera frame, metres; ``R_gt`` [3, 3], ``t_gt`` [3] map the category frame into
    the camera frame (x = R y + t, metres), as the SDK's pose does."""
    x = np.asarray(points_m, np.float64)                                          # [P, 3]
    if len(x) > OBSERVED_POINTS:
        x = x[farthest_point_order(x, OBSERVED_POINTS)]                           # [2048, 3]
    Y = densify_template(result.canonical_shape_object, est.densify)              # [M', 3] category frame, metres
    R, _, _ = icp_multi(x, Y, R_gt[None], np.asarray(t_gt, np.float64)[None], iters=iters,
                        bidirectional=not est.partial)
    return float(rotation_angle_deg(R[0], R_gt))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--category", required=True)
    ap.add_argument("--split", choices=["train", "test"], default="test")
    ap.add_argument("--n", type=int, default=0, help="views (evenly spaced; 0 = all)")
    ap.add_argument("--iters", type=int, default=0, help="ICP iterations of the ceiling fit (0: refine_iters + polish)")
    ap.add_argument("--json", help="write the per-view errors here")
    args = ap.parse_args()
    idx, samples = rendered_views(args.category, args.split, args.n)
    est = PoseEstimator(args.model, threads=1)
    iters = args.iters or max(1, est.refine_iters + est.polish)
    sdk, ceil = [], []
    for s in samples:
        r = est.predict_points(s["points_m"])
        sdk.append(float(rotation_angle_deg(r.rotation, s["rotation"])))
        ceil.append(ceiling_error(est, r, s["points_m"], s["rotation"], s["translation_m"], iters))
    e, c = np.array(sdk), np.array(ceil)                                          # [V] degrees
    miss = e >= 5
    parts = {"template": int(np.sum(miss & (c >= 5))), "near_miss": int(np.sum(miss & (c < 5) & (e < 20))),
             "wrong_basin": int(np.sum(miss & (c < 5) & (e >= 20)))}
    print(f"{args.model} ({args.category}/{args.split}, {len(e)} views, ceiling fit {iters} ICP iterations)")
    print(f"  SDK:              median {np.median(e):.3f}°  5° {np.mean(e < 5):.3f}  flips {np.mean(e > 150):.3f}")
    print(f"  template ceiling: median {np.median(c):.3f}°  5° {np.mean(c < 5):.3f}")
    print(f"  SDK misses (≥ 5°) {int(miss.sum())}: template {parts['template']}, near miss {parts['near_miss']}, "
          f"wrong basin {parts['wrong_basin']}")
    ok = e < 20
    if ok.sum() > 2:
        print(f"  views < 20°: correlation of SDK and ceiling errors {np.corrcoef(e[ok], c[ok])[0, 1]:.2f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"model": args.model, "category": args.category, "split": args.split, "iters": iters,
                       "views": [int(i) for i in idx], "sdk_deg": e.tolist(), "ceiling_deg": c.tolist(),
                       "misses": parts}, f)


if __name__ == "__main__":
    main()
