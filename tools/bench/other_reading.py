"""How often a partial model's other reading (``PoseResult.flip_rotation``) is right where its pose is turned.

    python tools/bench/other_reading.py --model car-partial [--category car] [--deg 10]

Runs the model (default profile) on its rendered partial test views and prints: how many poses are turned (rotation
error > 150°), the share of those whose ``flip_rotation`` lies within ``--deg`` and within 30° of the truth, and the
share of all views with the pose, or either of the two readings, within ``--deg``.

Convention: angles in degrees; shares of the test views.
"""
from __future__ import annotations

import argparse

import numpy as np

from equipose import PoseEstimator
from equipose.eval.metrics import FLIP_DEG, rotation_errors
from equipose.train.data.modelnet import default_data_root
from equipose.train.evaluation.evaluate import predict_onnx, test_dataset


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--category", help="the test set's category (default: the model's)")
    ap.add_argument("--deg", type=float, default=10.0)
    ap.add_argument("--cache-dir", dest="cache_dir")
    a = ap.parse_args(argv)
    est = PoseEstimator(a.model)
    ds = test_dataset(default_data_root(), a.category or est.category, "partial", est.num_points,
                      cache_dir=a.cache_dir)
    samples = [ds.raw(i) for i in range(len(ds))]
    R, *_, flips = predict_onnx(est, samples)
    if flips is None:
        raise SystemExit(f"{a.model} reports no other reading (it has no turn classifier)")
    truth = np.stack([s["rotation"] for s in samples])
    e, f = rotation_errors(R, truth), rotation_errors(flips, truth)             # [S] degrees
    turned = e > FLIP_DEG
    print(f"{a.model}: {len(e)} views, {int(turned.sum())} turned; of those, flip_rotation within {a.deg:g}° "
          f"{np.mean(f[turned] <= a.deg):.3f}, within 30° {np.mean(f[turned] <= 30.0):.3f}; within {a.deg:g}°: "
          f"the pose {np.mean(e <= a.deg):.3f}, either reading {np.mean(np.minimum(e, f) <= a.deg):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
