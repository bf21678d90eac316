"""Centre calibration of a tabletop model: the depth offset of a partial view's centre, fitted on rendered training
views, stored as ``centre_calibration`` for the ``centre`` stage (``equipose.runtime.stages.centre``).

    python -m equipose.train.evaluation.centre --model sdk/models/cup-tabletop.onnx [--views 200] [--seed 7]
        [--split train] [--write] [--json F] [--data-root DIR]

Each view (``equipose.train.data.occluded``: occluders, sensor noise; the training shapes' point clouds, so the test
shapes stay unseen) runs through ``PoseEstimator.predict`` four times, box and mask prompt, each without and with the
up prior "plane", with the stage off. The error of each centre along the camera ray (+ = beyond the truth) and
across it is measured; the offset is the shift along the ray that minimises the mean centre error of all results. ``--split test`` measures a file as it is (the stage at
its stored offset, or at ``--offset``) on the test shapes instead: the along-ray median then shows what is left.

Convention: metres, camera frame; the ray runs from the camera through the true centre.
"""
from __future__ import annotations

import datetime
import json
import pathlib
import sys

import numpy as np

from equipose.core.errors import ConfigError
from equipose.runtime.stages.centre import MAX_OFFSET_M
from equipose.train.evaluation.confidence import PROMPTS, RIGHT_M, occluded_views, view_results
from equipose.train.evaluation.fit_cli import fit_parser

__all__ = ["collect_centres", "fit_offset", "summarize_centres", "main"]

UPS = (None, "plane")


def collect_centres(est, views: int, seed: int, split: str = "train", data_root=None, progress: bool = True) -> list:
    """Rows {"view", "prompt", "up", "along" (m), "across" (m), "error" (m), "distance" (m, camera to the true centre),
    "occluded" (the hidden share)} of ``est`` on ``views`` rendered views of the ``split`` shapes of its tabletop
    category (the point-cloud shapes; cans lie on every ``LYING_EVERY``-th)."""
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.tabletop import TABLETOP, tabletop_sources
    if est.category not in TABLETOP:
        raise ConfigError(f"centre calibration renders tabletop scenes; {est.category!r} is not one of "
                          f"{', '.join(TABLETOP)}")
    sources = [s for s in tabletop_sources(data_root or default_data_root(), est.category, split)
               if "points" in s[1]]                                            # [(name, surfels, points)]
    rows = []
    for v, _, view, _ in occluded_views(sources, views, seed, est.metadata.get("shape_prior") == "cylinder",
                                        desc=f"centre {est.category}", progress=progress):
        ray = view.t / np.linalg.norm(view.t)                                  # [3] camera → true centre
        for prompt, up, r, _ in view_results(est, view, ups=UPS):
            e = np.asarray(r.translation, np.float64) - view.t                 # [3] m
            along = float(e @ ray)
            rows.append({"view": v, "prompt": prompt, "up": up or "none", "along": along,
                         "across": float(np.linalg.norm(e - along * ray)), "error": float(np.linalg.norm(e)),
                         "distance": float(np.linalg.norm(view.t)), "occluded": float(view.occluded)})
    return rows


def fit_offset(rows: list) -> float:
    """The offset (m, + = away from the camera) that minimises the rows' mean centre error (convex in the offset)."""
    from scipy.optimize import minimize_scalar
    if not rows:
        raise ConfigError("no results to fit the centre offset on; render more views")
    along = np.array([r["along"] for r in rows])                               # [R] m
    across = np.array([r["across"] for r in rows])                             # [R] m
    best = minimize_scalar(lambda o: float(np.mean(np.hypot(along + o, across))), bounds=(-MAX_OFFSET_M, MAX_OFFSET_M),
                           method="bounded", options={"xatol": 1e-5})
    return float(best.x)


def summarize_centres(rows: list, offset: float = 0.0) -> dict:
    """Per prompt × up and over all: results, along-ray median (m), centre error median and mean (m) and share
    within ``RIGHT_M``, as measured and with ``offset`` added along the ray."""
    def part(rs):
        along = np.array([r["along"] for r in rs])
        across = np.array([r["across"] for r in rs])
        moved = np.hypot(along + offset, across)
        return {"n": len(rs), "along_median_m": float(np.median(along)),
                "error_median_m": float(np.median([r["error"] for r in rs])),
                "error_mean_m": float(np.mean([r["error"] for r in rs])), "offset_error_mean_m": float(np.mean(moved)),
                "within_2cm": float(np.mean([r["error"] <= RIGHT_M for r in rs])),
                "offset_error_median_m": float(np.median(moved)), "offset_within_2cm": float(np.mean(moved <= RIGHT_M))}
    out = {"all": part(rows)}
    for p in PROMPTS:
        for u in ("none", "plane"):
            rs = [r for r in rows if r["prompt"] == p and r["up"] == u]
            if rs:
                out[f"{p}/{u}"] = part(rs)
    return out


def main(argv=None) -> int:
    ap = fit_parser(__doc__, seed=7, write_help="store the fitted offset in the model file (and its stand-alone "
                                                ".int8 sibling)")
    ap.add_argument("--split", choices=("train", "test"), default="train")
    ap.add_argument("--offset", type=float, help="--split test: metres along the ray instead of the file's (0 = "
                                                  "the stage off)")
    a = ap.parse_args(argv)
    from equipose import PoseEstimator
    if a.write and a.split != "train":
        raise ConfigError("--write fits on the training shapes: leave --split at train")
    if a.offset is not None and a.split == "train":
        raise ConfigError("--offset measures a file on --split test; the fit on training views runs with the stage off")
    offset = 0.0 if a.split == "train" else a.offset
    est = PoseEstimator(a.model, stages=None if offset is None else {"centre": {"offset": offset}})
    rows = collect_centres(est, a.views, a.seed, a.split, a.data_root)
    offset = fit_offset(rows) if a.split == "train" else 0.0
    summary = summarize_centres(rows, offset)
    name = pathlib.Path(a.model).name
    for key, s in summary.items():
        print(f"{name} {a.split} {key:10s} n {s['n']:4d}  along-ray median {s['along_median_m'] * 1e3:6.1f} mm  "
              f"centre error median / mean {s['error_median_m'] * 1e3:5.1f} / {s['error_mean_m'] * 1e3:5.1f} mm, "
              f"≤ 2 cm {s['within_2cm']:.3f}"
              + (f"  → with the offset {s['offset_error_median_m'] * 1e3:5.1f} / {s['offset_error_mean_m'] * 1e3:5.1f}"
                 f" mm, {s['offset_within_2cm']:.3f}" if offset else ""))
    if a.split == "train":
        print(f"{name}: offset {offset * 1e3:+.1f} mm along the ray")
    meta = {"along_ray_m": round(offset, 5), "fitted_on": f"{len(rows)} results on {a.views} rendered training views "
            f"(seed {a.seed}; box and mask prompts, without and with the up prior)",
            "date": datetime.date.today().isoformat()}
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"calibration": meta if a.split == "train" else None,
                                                    "summary": summary, "rows": rows}, indent=1))
    if a.write:
        from equipose.export.onnx_export import update_metadata_with_int8
        update_metadata_with_int8(a.model, centre_calibration=meta)   # and a stand-alone int8 sibling
    return 0


if __name__ == "__main__":
    sys.exit(main())
