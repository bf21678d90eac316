"""Per-stage latency of the SDK pipeline on one 640×480 frame (bundled PCL mug sample, bundled ``small`` model).

Usage: python tools/measure_sdk_pipeline.py [--runs 30] [--threads N] [--model M]
Prints the median and p90 (ms) of crop, FPS ordering, inference, selection and total for a box crop, for a batch of
three boxes (one ORT run), and the tabletop auto crop (``auto_masks``). Warm-up runs are excluded.
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from equipose import PoseEstimator
from equipose.crop import auto_masks
from equipose.models import demo_model_path
from equipose.samples import sample_objects, sample_path
from equipose.sources import FolderSource


def stats(values):
    v = np.asarray(values)
    return f"{np.median(v):7.2f} {np.percentile(v, 90):7.2f}"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--model", default=None)
    args = ap.parse_args()
    est = PoseEstimator(args.model or demo_model_path(), threads=args.threads)
    frame = next(iter(FolderSource(sample_path())))
    box = sample_objects()[0]["box"]
    print(f"model {est.path.name} (N={est.num_points}, M={est.num_canonical_points}), frame "
          f"{frame.depth.shape[1]}x{frame.depth.shape[0]}, box {box}, threads {args.threads or 'default'}, "
          f"{args.runs} runs; {platform.processor() or platform.machine()}")
    keys = ("crop", "fps", "inference", "selection", "total")
    for label, boxes in (("single box", [box]), ("batch of 3 boxes", [box, box, box])):
        rows = {k: [] for k in keys}
        wall = []
        for i in range(args.warmup + args.runs):
            t0 = time.perf_counter()
            res = est.predict_batch(frame.depth, frame.K, boxes=boxes, image_size=frame.image_size)
            w = (time.perf_counter() - t0) * 1e3
            if i >= args.warmup:
                for k in keys:
                    rows[k].append(sum(r.timings[k] for r in res) if k in ("crop", "fps", "selection")
                                   else res[0].timings[k] if k == "inference" else 0.0)
                wall.append(w)
        print(f"\n{label}: stage          median     p90 (ms)")
        for k in ("crop", "fps", "inference", "selection"):
            print(f"  {k:<22}{stats(rows[k])}")
        print(f"  {'end to end (wall)':<22}{stats(wall)}")
    am = []
    for i in range(args.warmup + max(5, args.runs // 3)):
        t0 = time.perf_counter()
        masks = auto_masks(frame.depth, frame.K, image_size=frame.image_size)
        if i >= args.warmup:
            am.append((time.perf_counter() - t0) * 1e3)
    print(f"\nauto crop (plane RANSAC + clustering, {len(masks)} object): {stats(am)} ms (median, p90)")


if __name__ == "__main__":
    main()
