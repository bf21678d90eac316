"""Per-object latency of the geometric stages on real test inputs: the default pipeline of each model, and the up
prior where asked. Prints median / p90 total and selection (post-processing) milliseconds.

    python tools/bench/stage_latency.py [--runs 100] [--threads 2] [--bare]

``--bare`` runs the same files with their flip-template, rest-facet and frame-prior stages switched off (metadata
cleared in memory), which prices those stages.

Rows: ``cup-tabletop`` (no stage: the reference), ``car-partial`` and ``airplane-complete`` (flip stage),
``car-complete``, ``chair-complete``, ``sofa-complete`` (rest-facet and frame-prior stages),
``laptop-partial`` with ``up`` given (up prior), ``mug-tabletop`` (handle stage). Inputs are the first ``--runs`` test
views / clouds of each category (``equipose.train.evaluate.test_dataset``), one object per call, as a camera loop
would run them.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

from equipose import PoseEstimator
from equipose.train.evaluation.evaluate import test_dataset

CASES = (("cup-tabletop", "cup", "partial", False), ("car-partial", "car", "partial", False),
         ("airplane-complete", "airplane", "complete", False), ("car-complete", "car", "complete", False),
         ("chair-complete", "chair", "complete", False), ("sofa-complete", "sofa", "complete", False), ("laptop-partial", "laptop", "partial", True),
         ("mug-tabletop", "mug", "partial", False))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--data-root", default=os.environ.get("EQUIPOSE_DATA", "../shared/data"))
    p.add_argument("--cache-dir", default="data_cache")
    p.add_argument("--bare", action="store_true", help="switch the flip-template, rest-facet and frame-prior stages off")
    a = p.parse_args(argv)
    print(f"{'model':16s} {'stage':26s} {'n':>4s} {'total ms (median / p90)':>24s} {'selection ms (median / p90)':>28s}")
    for name, cat, mode, with_up in CASES:
        est = PoseEstimator(name, threads=a.threads)
        if a.bare:
            est.metadata.pop("flip_templates", None)
            est.metadata.pop("rest_facet", None)
            est.metadata.pop("frame_priors", None)
        ds = test_dataset(a.data_root, cat, mode, est.num_points, cache_dir=a.cache_dir)
        samples = [ds.raw(i) for i in range(min(a.runs, len(ds)))]
        est.predict_points(samples[0]["points_m"])                              # warm-up
        tot, sel = [], []
        for s in samples:
            r = est.predict_points(s["points_m"], up=s["rotation"][:, 2] if with_up else None)
            tot.append(r.timings["total"]); sel.append(r.timings["selection"])
        stages = [label for key, label in (("flip_templates", "flip"), ("rest_facet", "rest facet"),
                                           ("frame_priors", "frame priors")) if est.metadata.get(key) is not None]
        stage = "up prior" if with_up else (" + ".join(stages) or ("handle" if est.handle is not None else "–"))
        print(f"{name:16s} {stage:26s} {len(tot):4d} {np.median(tot):11.1f} / {np.percentile(tot, 90):6.1f}"
              f"{np.median(sel):17.1f} / {np.percentile(sel, 90):6.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
