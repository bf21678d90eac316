"""Two model files side by side in one process: the same frame through both, alternately, so that the host's speed
drifts equally on both (a cleaner A/B than two ``equipose bench`` runs).

Usage: python tools/bench/ab_model_files.py OLD.onnx NEW.onnx [--runs 30] [--threads 2]
Give both files the same name (e.g. ``a/car-complete.onnx`` and ``b/car-complete.onnx``): the ``default`` profile
picks its per-model settings by the file's name. Prints the medians of each timing (ms) on the bundled sample frame
and the angle between the two poses (degrees).
"""
from __future__ import annotations

import argparse

import numpy as np

from equipose import PoseEstimator
from equipose.bench.harness import _sample_frame
from equipose.core.geometry import rotation_angle_deg

TIMINGS = ("total", "crop", "fps", "inference", "selection")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args(argv)
    ests = {"old": PoseEstimator(a.old, threads=a.threads), "new": PoseEstimator(a.new, threads=a.threads)}
    frame, box = _sample_frame()

    def predict(est):
        return est.predict_batch(frame.depth, frame.K, boxes=[box], depth_unit=frame.depth_unit,
                                 image_size=frame.image_size)[0]

    for _ in range(5):                                                          # warm-up
        for est in ests.values():
            predict(est)
    times = {k: {t: [] for t in TIMINGS} for k in ests}
    last = {}
    for i in range(a.runs):
        for k in (("old", "new") if i % 2 else ("new", "old")):                # alternate who goes first
            last[k] = predict(ests[k])
            for t in TIMINGS:
                times[k][t].append(last[k].timings[t])
    print(" | ".join(f"{t} {np.median(times['old'][t]):.2f} -> {np.median(times['new'][t]):.2f}" for t in TIMINGS),
          f"| pose difference {rotation_angle_deg(last['old'].rotation, last['new'].rotation):.2e} deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
