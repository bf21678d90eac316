"""Objects standing on a table: the SDK with and without the up prior (``up="plane"``: the frame's support plane).

Renders ModelNet test instances of a category standing on a table top (``equipose.train.scene``; camera 15–60° above
the table, random azimuth, the category's max radius = 1 m like the paper-style test set), crops each by its box
(the crop removes the table) and prints rotation mean / median / 5° / 10° / flip rate and the `ambiguous` flag's
honesty, for each model given (fp32 and int8 files are separate names).

    python tools/bench/upright_tabletop.py --category laptop --models laptop-partial,laptop-partial.int8 \
        [--views 5] [--limit 20] [--icp] [--json out.json]

``--icp`` adds ICP-60 + template (3 random training shapes, 256 observed points, 20 iterations; the paper's baseline)
on the same crops, without and with the rotation held about the plane's up (``equipose.runtime.upright.upright_icp``
from the 60 starts turned upright).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import pathlib
import sys
import time

import numpy as np
from tqdm import tqdm

from equipose import PoseEstimator
from equipose.core.geometry import rotation_angle_deg
from equipose.train.data.render_cache import modelnet_shapes
from equipose.train.data.scene import render_standing

CACHE_VERSION = 1


def standing_views(root, category: str, views: int, limit, cache_dir, seed: int = 0) -> dict:
    """Rendered frames (depth [S, H, W] uint16 mm, K [3, 3], R [S, 3, 3], t [S, 3], boxes [S, 4]), cached on disk."""
    key = hashlib.sha1(json.dumps([CACHE_VERSION, category, views, limit, seed]).encode()).hexdigest()[:10]
    path = pathlib.Path(cache_dir) / f"standing_{category}_{key}.npz"
    if path.is_file():
        return dict(np.load(path))
    rng = np.random.default_rng(seed)
    out, K = {"depth": [], "R": [], "t": [], "box": []}, None
    for _, shape, _ in tqdm(modelnet_shapes(root, category, "test", "npy1024", limit), desc=f"render {category}"):
        for _ in range(views):
            v = render_standing(shape, rng)
            if v["box"] is None:
                continue
            for k in out:
                out[k].append(v[k])
            K = v["K"]
    data = {**{k: np.asarray(v) for k, v in out.items()}, "K": K}
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(path, **data)
    return data


def _trans(terr, rot_err) -> dict:
    """Translation figures (metres; the category's max radius is 1 m) and the 5° 5 cm accuracy."""
    te = np.asarray(terr)
    return {"trans_mean_m": float(te.mean()), "trans_median_m": float(np.median(te)),
            "acc_5deg_5cm": float(np.mean((np.asarray(rot_err) <= 5) & (te <= 0.05)))}


def measure(model: str, data: dict, up) -> dict:
    est = PoseEstimator(model)
    errs, terr, amb, ms = [], [], [], []
    for depth, R, t, box in zip(data["depth"], data["R"], data["t"], data["box"]):
        r = est.predict(depth, data["K"], box=tuple(int(v) for v in box), up=up)
        errs.append(float(rotation_angle_deg(r.rotation, R)))
        terr.append(float(np.linalg.norm(r.translation - t)))
        amb.append(bool(r.ambiguous))
        ms.append(r.timings["selection"])
    e, a = np.array(errs), np.array(amb)
    flip = e > 150
    return {"model": model, "up": up or "none", "n": len(e), **_trans(terr, e), "rot_mean_deg": float(e.mean()),
            "rot_median_deg": float(np.median(e)), "acc_5deg": float(np.mean(e <= 5)),
            "acc_10deg": float(np.mean(e <= 10)), "flip_rate": float(flip.mean()), "ambiguous_rate": float(a.mean()),
            "flip_among_ambiguous": float(flip[a].mean()) if a.any() else None,
            "flip_among_unambiguous": float(flip[~a].mean()) if (~a).any() else None,
            "selection_ms_median": float(np.median(ms))}


def measure_icp(data: dict, root, category: str, model: str, seed: int = 0) -> list:
    """ICP-60 + template rows (none / plane) on the crops ``model``'s estimator makes of the same frames."""
    from equipose.core.geometry import farthest_point_order
    from equipose.core.icosahedral import ANCHORS
    from equipose.preprocess import find_support_plane
    from equipose.runtime.upright import resolve_plane_up, upright_icp
    from equipose.train.evaluation.evaluate import _icp_template_clouds
    from equipose.train.evaluation.icp import icp60
    est = PoseEstimator(model)
    clouds = _icp_template_clouds(root, category)
    pick = np.random.default_rng(seed).choice(len(clouds), size=3, replace=False)
    templates = [clouds[i][farthest_point_order(clouds[i], 512)].astype(np.float64) for i in pick]
    errs, terr = {"none": [], "plane": []}, {"none": [], "plane": []}
    for depth, R_true, t_true, box in tqdm(list(zip(data["depth"], data["R"], data["t"], data["box"])), desc="icp60",
                                           leave=False):
        crop = est.crop(depth, data["K"], box=tuple(int(v) for v in box))
        x = crop.points[farthest_point_order(crop.points, min(256, len(crop.points)))].astype(np.float64)
        up = resolve_plane_up(find_support_plane(depth.astype(np.float64) / 1000.0, data["K"]), crop.points)
        best = {"none": (np.inf, None), "plane": (np.inf, None)}
        for y in templates:                                                     # templates centred on their origin
            R, t, r = icp60(x, y, iters=20)
            best["none"] = min(best["none"], (r, R, t), key=lambda v: v[0])
            if up is not None:
                Rs, ts, rs = upright_icp(x, y, ANCHORS, x.mean(0) - ANCHORS @ y.mean(0), up, iters=20)
                j = int(np.argmin(rs))
                best["plane"] = min(best["plane"], (rs[j], Rs[j], ts[j]), key=lambda v: v[0])
        for k in errs:
            _, R, t = best[k] if best[k][1] is not None else best["none"]
            errs[k].append(float(rotation_angle_deg(R, R_true)))
            terr[k].append(float(np.linalg.norm(t - t_true)))
    rows = []
    for k, e in errs.items():
        e = np.array(e)
        rows.append({"model": "icp60+template", "up": k, "n": len(e), **_trans(terr[k], e), "rot_mean_deg": float(e.mean()),
                     "rot_median_deg": float(np.median(e)), "acc_5deg": float(np.mean(e <= 5)),
                     "acc_10deg": float(np.mean(e <= 10)), "flip_rate": float(np.mean(e > 150)),
                     "ambiguous_rate": 0.0, "flip_among_ambiguous": None, "flip_among_unambiguous": None,
                     "selection_ms_median": float("nan")})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--category", required=True)
    p.add_argument("--models", required=True, help="comma-separated model names or .onnx paths")
    p.add_argument("--views", type=int, default=5)
    p.add_argument("--limit", type=int, default=None, help="first K test instances")
    p.add_argument("--data-root", default=os.environ.get("EQUIPOSE_DATA", "../shared/data"))
    p.add_argument("--cache-dir", default="data_cache")
    p.add_argument("--icp", action="store_true", help="add ICP-60 + template rows")
    p.add_argument("--json")
    a = p.parse_args(argv)
    t0 = time.perf_counter()
    data = standing_views(a.data_root, a.category, a.views, a.limit, a.cache_dir)
    print(f"{len(data['R'])} views of {a.category} standing on a table ({time.perf_counter() - t0:.0f} s)")
    rows = [measure(m, data, up) for m in a.models.split(",") for up in (None, "plane")]
    if a.icp:
        rows += measure_icp(data, a.data_root, a.category, a.models.split(",")[0])
    print(f"{'model':22s} {'up':6s} {'mean':>7s} {'median':>7s} {'5°':>5s} {'10°':>5s} {'flip':>5s} {'t med m':>8s} "
          f"{'5°5cm':>6s} {'amb':>5s} {'flip|amb':>8s} {'flip|¬amb':>9s} {'sel ms':>7s}")
    for r in rows:
        fa = "–" if r["flip_among_ambiguous"] is None else f"{r['flip_among_ambiguous']:.2f}"
        fu = "–" if r["flip_among_unambiguous"] is None else f"{r['flip_among_unambiguous']:.2f}"
        print(f"{r['model']:22s} {r['up']:6s} {r['rot_mean_deg']:7.2f} {r['rot_median_deg']:7.2f} {r['acc_5deg']:5.2f} "
              f"{r['acc_10deg']:5.2f} {r['flip_rate']:5.2f} {r['trans_median_m']:8.3f} {r['acc_5deg_5cm']:6.2f} "
              f"{r['ambiguous_rate']:5.2f} {fa:>8s} {fu:>9s} "
              f"{r['selection_ms_median']:7.1f}")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"category": a.category, "views": a.views, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
