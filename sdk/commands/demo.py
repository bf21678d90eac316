"""``equipose demo``: the bundled sample (a real mug-on-table frame) through the bundled model.

Prints one line per object (R as a rotation vector, t in metres, confidence) and writes overlay PNGs to ``--out``
(default ``runs/demo``). For a symmetric model (cup, bowl, can) it also prints the angle between the predicted symmetry
axis and the frame's support-plane normal (a mug on a table stands upright: 0°). A model with random weights is
flagged: it shows the pipeline (depth → crop → FPS → ONNX → hypothesis selection → pose → overlay), not accuracy.
"""
from __future__ import annotations

import json
import pathlib

__all__ = ["add_arguments", "run"]


def add_arguments(p):
    p.add_argument("--out", default="runs/demo", help="folder for overlays and results (default: runs/demo)")
    p.add_argument("--model", default=None, help="model to use instead of the bundled one")
    p.add_argument("--profile", default="default", choices=["fast", "default", "accurate"],
                   help="speed / accuracy point of the pipeline (PoseEstimator(profile=...); docs/benchmarks.md)")
    p.add_argument("--threads", type=int, default=None, help="onnxruntime thread budget (default: all cores; a single object "
                   "of a light model runs on one)")
    p.add_argument("--boxes", action="store_true", help="use the sample's annotated boxes instead of auto crop")


def run(args) -> int:
    import cv2
    import numpy as np

    from equipose.preprocess import auto_masks, check_intrinsics
    from equipose.runtime.estimator import PoseEstimator
    from equipose.models import demo_model_path
    from equipose.runtime.overlay import draw_mask, draw_poses, to_bgr
    from equipose.samples import sample_objects, sample_path
    from equipose.sources import FolderSource

    model = pathlib.Path(args.model) if args.model else demo_model_path()
    est = PoseEstimator(model, threads=args.threads, profile=args.profile)
    frame = next(iter(FolderSource(sample_path("table_mug"))))
    print(f"equipose demo: sample 'table_mug' (PCL tutorial scene, BSD-3), {frame.depth.shape[1]}×{frame.depth.shape[0]} "
          f"depth; model {model.name} ({est.category}, {est.num_points} points, scale {est.scale} m/unit)")
    if est.kernels_s > 2.0:
        print(f"compiled the geometry kernels in {est.kernels_s:.0f} s (first run after an install; cached from now on)")
    if est.random_init:
        print("NOTE: this model has RANDOM WEIGHTS (an export for tests or benchmarks). The pipeline is real; "
              "the rotations it prints are not.")
    masks = [] if args.boxes else auto_masks(frame.depth, frame.K, image_size=frame.image_size)
    how = "auto crop (table plane + clusters)"
    if masks:
        results = est.predict_batch(frame.depth, frame.K, masks=masks, image_size=frame.image_size,
                                    return_errors=True)
    else:
        boxes = [o["box"] for o in sample_objects("table_mug")]
        how = "annotated boxes"
        results = est.predict_batch(frame.depth, frame.K, boxes=boxes, image_size=frame.image_size,
                                    return_errors=True)
    print(f"{len(results)} object(s) from {how}:")
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    K = check_intrinsics(frame.K, frame.depth.shape, frame.image_size)
    img = to_bgr(frame.rgb if frame.rgb is not None else frame.depth)
    for m in masks:
        img = draw_mask(img, m)
    from equipose.preprocess import depth_to_metres, find_support_plane
    from equipose.eval.realdata import axis_table_angle
    plane = find_support_plane(depth_to_metres(frame.depth, "mm"), K)            # (normal, offset) or None
    records = []
    for i, r in enumerate(results):
        if not hasattr(r, "rotation"):
            print(f"  object {i}: {r.error}: {r.message}")
            records.append(r.to_dict())
            continue
        r.object_id = i
        R = np.round(r.rotation, 3).tolist()
        print(f"  {r.summary()}")
        print(f"      R={R}  t(m)={np.round(r.translation, 3).tolist()}  "
              f"timings ms: " + ", ".join(f"{k} {v:.1f}" for k, v in r.timings.items()
                                        if k not in ("batch", "stages")))
        rec = r.to_dict()
        if r.symmetry_axis is not None and plane is not None:                 # a resting cylinder: upright or lying
            a = axis_table_angle(r.symmetry_axis, plane[0])
            rec["axis_vs_table"] = {"angle_deg": a.angle, "deviation_deg": a.deviation, "pose": a.pose}
            print(f"      symmetry axis vs table normal: {a.angle:.1f}° → {a.pose}, {a.deviation:.1f}° from the "
                  "nearer of upright/lying")
        records.append(rec)
    cv2.imwrite(str(out / "overlay.png"), draw_poses(img, K, [r for r in results if hasattr(r, "rotation")]))
    cv2.imwrite(str(out / "depth.png"), to_bgr(frame.depth))
    (out / "results.json").write_text(json.dumps({"model": est.info, "objects": records}, indent=1))
    print(f"overlays: {out / 'overlay.png'}, {out / 'depth.png'}; results: {out / 'results.json'}")
    return 0 if any(hasattr(r, "rotation") for r in results) else 1
