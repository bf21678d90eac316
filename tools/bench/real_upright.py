"""Real RealSense tabletop frames without pose labels: does a standing cup, mug, bowl or can come out upright?

Usage: python tools/bench/real_upright.py [--boxes tools/bench/data/uoc_boxes.toml] [--data DIR] [--profile default]
    [--models-from DIR] [--json FILE] [--overlays DIR]
Every object listed in the boxes file (hand-drawn boxes on ``realsense_tabletop_uoc``, nine 640 × 480 frames of
mugs, cups, bowls and cans among other things, some with something in front of them) stands upright, so its true
symmetry axis is the frame's support-plane normal (``equipose.preprocess.find_support_plane``, the camera side
positive = up). Each object runs through ``PoseEstimator.predict`` with its box, without and with ``up="plane"``, and
through the SDK's own segmentation (``predict_auto``: the detection whose pixels' bounding box overlaps the hand box
most, IoU ≥ 0.3).

Per result: the axis error against the normal (degrees; signed for cups, mugs and bowls, whose axis points out of the
opening, so upside down = 180°; sign-folded for cans), the confidence, ``ambiguous``, ``occlusion`` and
``handle_visible``. A result is *wrong* when its axis is more than 30° off; *confident-wrong* when it is wrong with
confidence > 0.5 and not ambiguous. The mugs' turn about their axis (the handle) has no label here and is not scored.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import tomllib

import cv2
import numpy as np

from equipose import PoseEstimator
from equipose.core.errors import EquiposeError
from equipose.preprocess import auto_masks, depth_to_metres, find_support_plane, region_bounds

WRONG_DEG = 30.0
HERE = pathlib.Path(__file__).resolve().parent


def axis_error(result, up: np.ndarray, unsigned: bool) -> float:
    """Degrees between the result's symmetry axis (category +z) and ``up`` [3] (camera frame)."""
    axis = result.symmetry_axis if result.symmetry_axis is not None else result.rotation[:, 2]
    c = float(axis @ up / np.linalg.norm(axis))
    return float(np.degrees(np.arccos(np.clip(abs(c) if unsigned else c, -1.0, 1.0))))


def iou(a, b) -> float:
    """Intersection over union of two (x0, y0, x1, y1) boxes."""
    w = max(0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / float((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


def row_of(obj: dict, prompt: str, result, up: np.ndarray, unsigned: bool) -> dict:
    err = axis_error(result, up, unsigned)
    return {"frame": obj["frame"], "name": obj["name"], "model": obj["model"], "prompt": prompt,
            "front": obj.get("front", ""), "axis_deg": round(err, 2), "confidence": round(float(result.confidence), 3),
            "ambiguous": bool(result.ambiguous), "occlusion": float(getattr(result, "occlusion", 0.0) or 0.0),
            "handle_visible": getattr(result, "handle_visible", None),
            "ms": round(float(result.timings.get("total", 0.0)), 2),
            "confident_wrong": bool(err > WRONG_DEG and result.confidence > 0.5 and not result.ambiguous)}


def main(argv=None) -> int:
    root = pathlib.Path(os.environ.get("EQUIPOSE_DATA", HERE.parents[1].parent / "shared" / "data"))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--boxes", default=str(HERE / "data" / "uoc_boxes.toml"))
    ap.add_argument("--data", default=str(root / "realsense_tabletop_uoc"))
    ap.add_argument("--profile", default="default")
    ap.add_argument("--models-from", help="a folder of model files to use instead of the shipped ones of the same "
                                          "name (<name>.onnx), e.g. candidates before shipping")
    ap.add_argument("--json", help="write the per-object rows here")
    ap.add_argument("--overlays", help="a folder for one annotated JPEG per frame (box prompt, no up prior)")
    a = ap.parse_args(argv)
    data = pathlib.Path(a.data)
    cam = json.loads((data / "camera_params.json").read_text())
    K = np.array([[cam["fx"], 0.0, cam["x_offset"]], [0.0, cam["fy"], cam["y_offset"]], [0.0, 0.0, 1.0]])
    objects = tomllib.loads(pathlib.Path(a.boxes).read_text())["object"]
    def model_file(name):
        own = pathlib.Path(a.models_from or ".") / f"{name}.onnx"
        return str(own) if a.models_from and own.is_file() else name
    estimators = {m: PoseEstimator(model_file(m), profile=a.profile) for m in sorted({o["model"] for o in objects})}
    rows, drawn = [], {}
    for frame in sorted({o["frame"] for o in objects}):
        depth = cv2.imread(str(data / f"{frame:06d}-depth.png"), cv2.IMREAD_UNCHANGED)
        plane = find_support_plane(depth_to_metres(depth, "mm"), K)
        if plane is None:
            print(f"frame {frame}: no support plane found; its objects are skipped", file=sys.stderr)
            continue
        up = np.asarray(plane[0], np.float64)
        masks = auto_masks(depth, K, depth_unit="mm")                          # the SDK's own segmentation
        for obj in (o for o in objects if o["frame"] == frame):
            est = estimators[obj["model"]]
            unsigned = est.metadata.get("shape_prior") == "cylinder"
            x0, y0, x1, y1 = obj["box"]
            for prompt, up_prior in (("box", None), ("box+plane", "plane")):
                try:
                    r = est.predict(depth, K, box=(x0, y0, x1 - x0, y1 - y0), depth_unit="mm", up=up_prior)
                except EquiposeError as e:
                    rows.append({"frame": frame, "name": obj["name"], "model": obj["model"], "prompt": prompt,
                                 "error": type(e).__name__})
                    continue
                rows.append(row_of(obj, prompt, r, up, unsigned))
                if prompt == "box" and a.overlays:
                    drawn.setdefault(frame, []).append((obj, r))
            best = max(masks, key=lambda m: iou(region_bounds({"mask": m}, m.shape), obj["box"]), default=None)
            result = None
            if best is not None and iou(region_bounds({"mask": best}, best.shape), obj["box"]) >= 0.3:
                result = est.predict_batch(depth, K, masks=[best], depth_unit="mm", return_errors=True)[0]
            if result is not None and not isinstance(result, Exception):
                rows.append(row_of(obj, "auto", result, up, unsigned))
            else:
                rows.append({"frame": frame, "name": obj["name"], "model": obj["model"], "prompt": "auto",
                             "error": "not segmented"})
    print(f"{'frame':>5s} {'object':24s} {'model':14s} {'box °':>7s} {'conf':>5s} {'amb':>4s} {'occl':>5s} "
          f"{'+plane conf':>11s} {'auto °':>7s} {'conf':>5s}  in front")
    by = {(r["frame"], r["name"], r["prompt"]): r for r in rows}
    for obj in objects:
        b, p, u = (by.get((obj["frame"], obj["name"], k), {}) for k in ("box", "box+plane", "auto"))
        print(f"{obj['frame']:5d} {obj['name'][:24]:24s} {obj['model'][:14]:14s} "
              f"{b.get('axis_deg', float('nan')):7.1f} {b.get('confidence', float('nan')):5.2f} "
              f"{'yes' if b.get('ambiguous') else '':>4s} {b.get('occlusion', float('nan')):5.2f} "
              f"{p.get('confidence', float('nan')):11.2f} {u.get('axis_deg', float('nan')):7.1f} "
              f"{u.get('confidence', float('nan')):5.2f}  {obj.get('front', '')}")
    print()
    print(f"{'prompt':10s} {'model':14s} {'n':>3s} {'axis° med':>9s} {'≤ 10°':>6s} {'wrong':>5s} {'conf-wrong':>10s} "
          f"{'errors':>6s} {'ms med':>6s}")
    for prompt in ("box", "box+plane", "auto"):
        for model in [*sorted(estimators), "all"]:
            sel = [r for r in rows if r["prompt"] == prompt and (model == "all" or r["model"] == model)]
            ok = [r for r in sel if "axis_deg" in r]
            if not sel:
                continue
            ax = np.array([r["axis_deg"] for r in ok]) if ok else np.array([np.nan])
            print(f"{prompt:10s} {model:14s} {len(ok):3d} {np.median(ax):9.1f} {np.mean(ax <= 10):6.2f} "
                  f"{int(np.sum(ax > WRONG_DEG)):5d} {sum(r['confident_wrong'] for r in ok):10d} "
                  f"{len(sel) - len(ok):6d} {np.median([r['ms'] for r in ok]) if ok else float('nan'):6.1f}")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(rows, indent=1))
    if a.overlays:
        from equipose.runtime.overlay import draw_poses
        out = pathlib.Path(a.overlays)
        out.mkdir(parents=True, exist_ok=True)
        for frame, items in drawn.items():
            image = cv2.imread(str(data / f"{frame:06d}-color.png"))
            for obj, _ in items:
                cv2.rectangle(image, tuple(obj["box"][:2]), (obj["box"][2] - 1, obj["box"][3] - 1), (255, 255, 255), 1)
            image = draw_poses(image, K, [r for _, r in items])
            cv2.imwrite(str(out / f"uoc_{frame:06d}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, 80])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
