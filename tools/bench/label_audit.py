"""Test instances whose label frame disagrees with their own mirror plane, beside the model's error on them.

Usage: python tools/bench/label_audit.py --model sdk/models/airplane-complete.onnx --category airplane
    [--mode complete|partial] [--min-yaw 3] [--json FILE]

ModelNet's category frames were made consistent with the 24 rotations of the cube (shared/data/SOURCES.md), so an
instance whose mesh was yawed by some other angle keeps that yaw in its label. Airplanes, cars, chairs and sofas are
mirror-symmetric about a vertical plane of the frame (normal +x: the yz-plane; sofas +y); this script finds each
test cloud's own mirror plane among the planes through its centroid with a normal in the xy-plane (yaw about +z, degrees, 1° grid over ±90° and then
0.1° steps; score: mean nearest-neighbour distance from the mirrored cloud to the cloud, model units).

An instance has a **mirror label** when its own mirror plane is ≥ ``--min-yaw`` off the frame's and clearly
better (score at its yaw < ``MIRROR_CLEAR`` × the score at 0): a fact of the data alone, no model involved.

The model then runs through ``equipose.PoseEstimator`` on the test set of ``equipose eval`` (complete: 5 rotations
per instance; partial: 5 rendered views). Per view, the error rotation in the category frame is E = R_trueᵀ R_pred;
per instance the script reports the median angle of E, its mean rotation vector (degrees), how far the views' E lie
from that mean, and ``off_yaw``: the largest angle between a view's E and the turn about z by the mirror yaw (small =
the model followed the shape's mirror plane, not the label). Listed: every instance with a median error over 5°,
a mirror yaw of at least ``--min-yaw`` or a suspect listed in SOURCES.md, and the 5° accuracy with and without the
listed suspects and the mirror labels.
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from equipose.eval.metrics import rotation_errors
from equipose.train.evaluation.evaluate import SUSPECT_TEST_INSTANCES, _instance_names, predict_onnx, test_dataset
from equipose.train.data.modelnet import default_data_root, load_modelnet

MIRROR_NORMAL_YAW = {"airplane": 0.0, "car": 0.0, "chair": 0.0, "sofa": 90.0}   # the frame's mirror normal, ° about z
MIRROR_CLEAR = 0.75          # a mirror label's plane must score below this share of the frame's


def mirror_yaw(cloud: np.ndarray, base: float = 0.0) -> tuple:
    """Yaw (degrees about +z, from ``base``) of the mirror plane of ``cloud`` [P, 3] (category frame, model units)
    through its centroid, normal in the xy-plane; ``base`` = the frame's own mirror normal (0: +x, the yz-plane).
    Returns (yaw, score at yaw, score at 0)."""
    x = cloud - cloud.mean(0)                                                          # [P, 3]
    tree = cKDTree(x)

    def score(yaw_deg: float) -> float:
        a = np.radians(base + yaw_deg)
        n = np.array([np.cos(a), np.sin(a), 0.0])                                      # [3] plane normal
        return float(tree.query(x - 2.0 * np.outer(x @ n, n))[0].mean())

    coarse = np.arange(-89.0, 90.5, 1.0)
    best = coarse[int(np.argmin([score(y) for y in coarse]))]
    fine = best + np.arange(-1.0, 1.05, 0.1)
    yaw = float(fine[int(np.argmin([score(y) for y in fine]))])
    return yaw, score(yaw), score(0.0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True, help="an exported .onnx model or a shipped name")
    ap.add_argument("--category", required=True)
    ap.add_argument("--mode", choices=("complete", "partial"), default="complete")
    ap.add_argument("--min-yaw", type=float, default=3.0, help="degrees: smallest mirror yaw called a label error")
    ap.add_argument("--json", help="write the per-instance table here")
    a = ap.parse_args(argv)
    if a.category not in MIRROR_NORMAL_YAW:
        raise SystemExit(f"no mirror plane known for {a.category!r}: one of {sorted(MIRROR_NORMAL_YAW)}")
    base = MIRROR_NORMAL_YAW[a.category]

    root = default_data_root()
    from equipose import PoseEstimator
    est = PoseEstimator(a.model)
    ds = test_dataset(root, a.category, a.mode, est.num_points)
    samples = [ds.raw(i) for i in range(len(ds))]
    names = _instance_names(ds, root, a.category, a.mode, None)
    R, _, est, _, symmetry, _, _ = predict_onnx(est, samples)
    R_gt = np.stack([s["rotation"] for s in samples])                                  # [S, 3, 3]
    err = rotation_errors(R, R_gt, symmetry, a.category == "can")                      # [S] degrees
    inst = np.array([s["instance"] for s in samples])                                  # [S]
    test_clouds, test_ids = load_modelnet(root, a.category, "test", None)
    clouds = {nm: np.asarray(c, np.float64) for c, nm in zip(test_clouds, test_ids)}

    suspects = set(SUSPECT_TEST_INSTANCES.get(a.category, ()))
    rows = []
    for k in np.unique(inst):
        name = names[k]
        views = np.flatnonzero(inst == k)
        E = Rotation.from_matrix(np.einsum("sji,sjk->sik", R_gt[views], R[views]))   # [V] R_trueᵀ R_pred
        mean = E.mean()
        spread = float(np.degrees(np.max((E * mean.inv()).magnitude())))
        yaw, s_yaw, s_zero = mirror_yaw(clouds[name], base)
        to_yaw = (E * Rotation.from_euler("z", yaw, degrees=True).inv()).magnitude()  # [V] rad
        rows.append({"instance": name, "id": name.split("_")[-1], "views": int(len(views)),
                     "median_error_deg": float(np.median(err[views])),
                     "error_rotvec_deg": [round(float(v), 2) for v in mean.as_rotvec(degrees=True)],
                     "spread_deg": round(spread, 2), "mirror_yaw_deg": round(yaw, 1),
                     "mirror_score": round(s_yaw, 4), "mirror_score_at_0": round(s_zero, 4),
                     "listed_suspect": name.split("_")[-1] in suspects,
                     "off_yaw_deg": round(float(np.degrees(to_yaw.max())), 2),
                     "mirror_label": bool(abs(yaw) >= a.min_yaw and s_yaw < MIRROR_CLEAR * s_zero)})

    print(f"{a.category} / {a.mode}: {len(samples)} views of {len(rows)} test instances, {a.model}")
    print("| instance | median error ° | error rotation vector ° (mean of views) | spread ° | mirror yaw ° | "
          "mirror score at yaw / at 0 | off yaw ° | listed suspect | mirror label |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in sorted(rows, key=lambda r: -r["median_error_deg"]):
        if r["median_error_deg"] > 5 or abs(r["mirror_yaw_deg"]) >= a.min_yaw or r["listed_suspect"]:
            print(f"| {r['id']} | {r['median_error_deg']:.1f} | {r['error_rotvec_deg']} | {r['spread_deg']:.1f} | "
                  f"{r['mirror_yaw_deg']:+.1f} | {r['mirror_score']:.4f} / {r['mirror_score_at_0']:.4f} | "
                  f"{r['off_yaw_deg']:.1f} | {'yes' if r['listed_suspect'] else ''} | "
                  f"{'**yes**' if r['mirror_label'] else ''} |")
    listed = {r["instance"] for r in rows if r["listed_suspect"]}
    yawed = {r["instance"] for r in rows if r["mirror_label"]}
    for label, drop in (("all views", set()), ("without the listed suspects", listed),
                        ("without the listed suspects and the mirror labels", listed | yawed)):
        keep = np.array([names[k] not in drop for k in inst])
        print(f"5° accuracy {label}: {np.mean(err[keep] < 5):.3f} (n = {int(keep.sum())}), "
              f"median {np.median(err[keep]):.2f}°")
    print("mirror labels:", ",".join(sorted(r["id"] for r in rows if r["mirror_label"])) or "none")
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"model": a.model, "category": a.category, "mode": a.mode, "instances": rows}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
