"""How honest is the ``ambiguous`` flag? Flip rate (errors > 150°) overall, among results flagged ambiguous and among
those not flagged, through the SDK on a test set; the same by ``confidence`` and, for files that run rotated input
copies, by ``agreement`` (the fraction of copies agreeing with the consensus).

Usage: python tools/bench/flip_honesty.py MODEL CATEGORY MODE [--limit K] [--exclude-suspects]
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

from equipose import PoseEstimator
from equipose.eval.metrics import rotation_errors
from equipose.train.evaluation.evaluate import SUSPECT_TEST_INSTANCES, _instance_names, test_dataset
from equipose.train.data.datasets import default_data_root


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("category")
    ap.add_argument("mode", choices=["complete", "partial"])
    ap.add_argument("--limit", type=int)
    ap.add_argument("--exclude-suspects", action="store_true")
    ap.add_argument("--cache-dir")
    a = ap.parse_args(argv)
    est = PoseEstimator(a.model)
    root = default_data_root()
    ds = test_dataset(root, a.category, a.mode, est.num_points, limit=a.limit, cache_dir=a.cache_dir)
    samples = [ds.raw(i) for i in range(len(ds))]
    if a.exclude_suspects:
        names = _instance_names(ds, root, a.category, a.mode, a.limit)
        bad = {k for k, n in enumerate(names) if n.split("_")[-1] in SUSPECT_TEST_INSTANCES.get(a.category, ())}
        samples = [s for s in samples if s["instance"] not in bad]
    res = [est.predict_points(s["points_m"]) for s in samples]
    err = rotation_errors(np.stack([r.rotation for r in res]), np.stack([s["rotation"] for s in samples]),
                          est.symmetry)
    amb = np.array([r.ambiguous for r in res])
    flip = err > 150.0
    print(f"{a.model} on {a.category}/{a.mode} (n = {len(samples)}): median {np.median(err):.2f}°, 5° "
          f"{np.mean(err <= 5):.2f}, flip rate {flip.mean():.2f}")
    print(f"  flagged ambiguous: {amb.mean():.2f} of results; flip rate among them "
          f"{flip[amb].mean() if amb.any() else float('nan'):.2f}, among the rest "
          f"{flip[~amb].mean() if (~amb).any() else float('nan'):.2f}; flips flagged: "
          f"{amb[flip].mean() if flip.any() else float('nan'):.2f}")
    conf = np.array([r.confidence for r in res])
    for q in (0.1, 0.3, 0.5):
        keep = conf >= q
        print(f"  confidence ≥ {q}: {keep.mean():.2f} of results, flip rate {flip[keep].mean() if keep.any() else float('nan'):.2f}, "
              f"median {np.median(err[keep]) if keep.any() else float('nan'):.2f}°")
    if res and res[0].agreement is not None:
        agree = np.array([r.agreement for r in res])
        for q in (0.5, 0.75, 1.0):
            keep = agree >= q
            print(f"  agreement ≥ {q}: {keep.mean():.2f} of results, flip rate "
                  f"{flip[keep].mean() if keep.any() else float('nan'):.2f}, median "
                  f"{np.median(err[keep]) if keep.any() else float('nan'):.2f}°, 5° "
                  f"{np.mean(err[keep] <= 5) if keep.any() else float('nan'):.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
