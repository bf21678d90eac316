"""Per-stage latency of the SDK pipeline on one 640×480 frame (bundled PCL mug sample, bundled ``small`` model).

Usage: python tools/bench/measure_sdk_pipeline.py [--runs 30] [--threads 1] [--model M]
Runs the stages of ``PoseEstimator.predict`` one by one (crop incl. depth validation and the support-plane fit, FPS
ordering + centring/scaling, onnxruntime inference, hypothesis selection + calibration + result) and prints, per stage,
the median and p90 of wall time and of the calling thread's CPU time (``time.thread_time``; with ``--threads 1``
onnxruntime runs in the calling thread, so CPU time is a load-independent figure on a shared machine). Also the
batched form (3 boxes, one ORT run) and the tabletop auto crop. Warm-up runs are excluded.
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from equipose import PoseEstimator
from equipose import preprocess as C
from equipose.models import demo_model_path
from equipose.samples import sample_objects, sample_path
from equipose.sources import FolderSource


def _stages(est, frame, box):
    """One pass of the predict pipeline; returns {stage: (wall ms, cpu ms)}."""
    out, w, c = {}, time.perf_counter, time.thread_time

    def mark(name, t0, c0):
        out[name] = ((w() - t0) * 1e3, (c() - c0) * 1e3)

    t0, c0 = w(), c()
    d = C.depth_to_metres(frame.depth, frame.depth_unit)
    K = C.check_intrinsics(frame.K, d.shape, frame.image_size)
    crop = C.crop_points(d, K, box=box, depth_unit="m", check_plausible=False)
    mark("crop", t0, c0)
    t0, c0 = w(), c()
    prep = C.prepare_points(crop.points, est.num_points, est.scale)
    mark("fps", t0, c0)
    t0, c0 = w(), c()
    outputs = est.run_model(prep.model_points[None])
    mark("inference", t0, c0)
    t0, c0 = w(), c()
    est._finish(outputs, 0, prep)
    mark("selection", t0, c0)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--model", default=None)
    args = ap.parse_args()
    est = PoseEstimator(args.model or demo_model_path(), threads=args.threads)
    frame = next(iter(FolderSource(sample_path())))
    box = sample_objects()[0]["box"]
    print(f"model {est.path.name} (N={est.num_points}, M={est.num_canonical_points}), frame "
          f"{frame.depth.shape[1]}x{frame.depth.shape[0]}, box {box}, ORT threads {args.threads}, {args.runs} runs, "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    rows = {}
    for i in range(args.warmup + args.runs):
        r = _stages(est, frame, box)
        if i >= args.warmup:
            for k, v in r.items():
                rows.setdefault(k, []).append(v)
    print("\nsingle box          wall median   p90 | thread-CPU median   p90  (ms)")
    tot_w, tot_c = 0.0, 0.0
    for k, v in rows.items():
        a = np.asarray(v)
        tot_w += np.median(a[:, 0]); tot_c += np.median(a[:, 1])
        print(f"  {k:<16}{np.median(a[:, 0]):12.2f}{np.percentile(a[:, 0], 90):7.2f} |"
              f"{np.median(a[:, 1]):17.2f}{np.percentile(a[:, 1], 90):7.2f}")
    print(f"  {'sum of medians':<16}{tot_w:12.2f}        |{tot_c:17.2f}")
    wall = []
    for i in range(args.warmup + args.runs):
        t0 = time.perf_counter()
        res = est.predict_batch(frame.depth, frame.K, boxes=[box] * 3, image_size=frame.image_size)
        if i >= args.warmup:
            wall.append(((time.perf_counter() - t0) * 1e3, res[0].timings["inference"]))
    a = np.asarray(wall)
    print(f"\nbatch of 3 boxes (one ORT run, batch 3): end-to-end wall median {np.median(a[:, 0]):.1f} ms, "
          f"inference {np.median(a[:, 1]):.1f} ms")
    am = []
    for i in range(args.warmup + max(5, args.runs // 3)):
        t0 = time.perf_counter()
        masks = C.auto_masks(frame.depth, frame.K, image_size=frame.image_size)
        if i >= args.warmup:
            am.append((time.perf_counter() - t0) * 1e3)
    print(f"auto crop (plane RANSAC + hull + clustering, {len(masks)} object): wall median {np.median(am):.1f} ms")
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
