"""Instance-level mode on a real YCB-Video frame: ms per object, the fit, the flags, an overlay.

Usage: python tools/bench/instance_real.py [--boxes tools/bench/data/ycb_demo_boxes.toml] [--data DIR]
    [--seed-model can-tabletop] [--runs 5] [--threads 2] [--json FILE] [--overlay FILE]
Each boxed object of ``ycb_posecnn/demo_images`` (hand-drawn boxes; the frames carry no pose annotations) runs through
``PoseEstimator(seed model, model_points=its points.xyz)`` with its box. Printed per object: median ms of ``--runs``
``predict`` calls after one warm-up (and the stage split of the last), confidence, ``ambiguous``, the fit — the
share of the crop's points within 5 mm of the posed model and their RMS distance (mm) — and the overlay draws each
posed model's points in its own colour over the colour image. Without ground truth the fit and the overlay say
whether a pose sits on its object, not its ADD-S. Depth: uint16 in 1e-4 m (YCB-Video); K: the colour camera's.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time
import tomllib

import cv2
import numpy as np
from scipy.spatial import cKDTree

from equipose import PoseEstimator
from equipose.runtime.overlay import project

HERE = pathlib.Path(__file__).resolve().parent
DATA = HERE.parents[2] / "shared" / "data" / "ycb_posecnn"
K_COLOUR = np.array([[1066.778, 0.0, 312.9869], [0.0, 1067.487, 241.3109], [0.0, 0.0, 1.0]])   # camera.json
DEPTH_UNIT = 1e-4               # metres per depth unit (YCB-Video)
NEAR_M = 0.005                  # a crop point within this of the posed model counts as explained
COLOURS = [(0, 255, 0), (255, 0, 255), (0, 255, 255), (255, 128, 0), (0, 0, 255), (255, 255, 0)]   # BGR


def crop_fit(result, crop: np.ndarray, model_points: np.ndarray) -> tuple:
    """(share of the ``crop`` [P, 3] m points within ``NEAR_M`` of the posed model, their RMS distance in mm)."""
    d, _ = cKDTree(model_points @ result.rotation.T + result.translation).query(crop)
    near = d < NEAR_M
    return float(near.mean()), float(np.sqrt(np.mean(d[near] ** 2)) * 1e3) if near.any() else None


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boxes", default=str(HERE / "data" / "ycb_demo_boxes.toml"))
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--seed-model", default="can-tabletop", help="the network whose hypotheses seed the ICP")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json", help="write per-object rows here")
    ap.add_argument("--overlay", help="write the overlay (PNG/JPEG) here")
    a = ap.parse_args(argv)
    data = pathlib.Path(a.data)
    objects = tomllib.loads(pathlib.Path(a.boxes).read_text())["object"]
    frames, canvas, rows = {}, {}, []
    print(f"{'object':22s} {'ms':>6s} {'crop':>5s} {'infer':>5s} {'select':>6s} {'conf':>5s} amb   fit≤5mm  rms mm")
    for k, obj in enumerate(objects):
        f = obj["frame"]
        if f not in frames:
            depth = cv2.imread(str(data / "demo_images" / f"{f}-depth.png"), cv2.IMREAD_UNCHANGED)
            frames[f] = depth                                                   # [H, W] uint16, 1e-4 m
            canvas[f] = cv2.imread(str(data / "demo_images" / f"{f}-color.png"))
        P = np.loadtxt(data / "models" / obj["model"] / "points.xyz")[:, :3]   # [M, 3] metres, object frame
        est = PoseEstimator(a.seed_model, model_points=P, threads=a.threads)
        x0, y0, x1, y1 = obj["box"]
        box = (x0, y0, x1 - x0, y1 - y0)                                        # (x, y, w, h), as predict takes it
        est.predict(frames[f], K_COLOUR, box=box, depth_unit=DEPTH_UNIT)               # warm-up
        ms = []
        for _ in range(a.runs):
            t0 = time.perf_counter()
            r = est.predict(frames[f], K_COLOUR, box=box, depth_unit=DEPTH_UNIT)
            ms.append((time.perf_counter() - t0) * 1e3)
        tried = r.extras.get("clusters_tried") or [{}]
        kept = 0 if r.extras.get("cluster_choice") != "fit" else \
            min(range(len(tried)), key=lambda i: tried[i]["see_through"])       # the crop the pose was found on
        gate = {k: v for k, v in tried[kept].items() if k in ("min_depth", "max_depth")}
        crop = est.crop(frames[f], K_COLOUR, box=box, depth_unit=DEPTH_UNIT, **gate).points   # [P, 3] m
        share, rms = crop_fit(r, np.asarray(crop, np.float64), P)
        tm = r.timings
        row = {"frame": f, "model": obj["model"], "front": obj.get("front", ""), "ms": round(float(np.median(ms)), 2),
               "crop_ms": round(tm["crop"], 2), "inference_ms": round(tm["inference"], 2),
               "selection_ms": round(tm["selection"], 2), "confidence": round(float(r.confidence), 3),
               "ambiguous": bool(r.ambiguous), "fit_share": share, "fit_rms_mm": rms,
               "clusters": r.crop.get("clusters"), "cluster_choice": r.extras.get("cluster_choice"),
               "clusters_tried": r.extras.get("clusters_tried"),
               "rotation": r.rotation.tolist(), "translation_m": r.translation.tolist()}
        rows.append(row)
        print(f"{obj['model']:22s} {row['ms']:6.1f} {row['crop_ms']:5.1f} {row['inference_ms']:5.1f} "
              f"{row['selection_ms']:6.1f} {row['confidence']:5.2f} {str(row['ambiguous']):5s} "
              f"{share:7.2f}  {rms if rms is None else round(rms, 2)!s:>6s}")
        img = canvas[f]
        uv, front = project(P @ r.rotation.T + r.translation, K_COLOUR)         # [M, 2] pixels, [M] bool
        for u, v in uv[front].astype(int):
            if 0 <= u < img.shape[1] and 0 <= v < img.shape[0]:
                cv2.circle(img, (int(u), int(v)), 1, COLOURS[k % len(COLOURS)], -1)
        cv2.rectangle(img, (x0, y0), (x1 - 1, y1 - 1), COLOURS[k % len(COLOURS)], 1)
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(rows, indent=1))
    if a.overlay:
        for f, img in canvas.items():
            out = pathlib.Path(a.overlay)
            cv2.imwrite(str(out if len(canvas) == 1 else out.with_name(f"{out.stem}_{f}{out.suffix}")), img)
    return 0


if __name__ == "__main__":
    sys.exit(main())
