"""Instance-level mode on the annotated GraspNet frame: ADD-S against its ground-truth poses, with how well those poses
fit the depth themselves.

Usage: python tools/bench/instance_graspnet.py [--data DIR] [--seed-model can-tabletop] [--runs 5] [--json FILE]
The frame (``realsense_graspnet_example``: RealSense D435, 1280 × 720, depth in mm, ``meta.mat`` poses model → camera)
holds four YCB objects whose YCB-Video model points ship in ``ycb_posecnn/models`` (GraspNet ids 000 cracker box,
002 tomato soup can, 005 banana, 008 power drill). It has no label image, so each object's prompt is made from its
annotation: its model points posed by the ground truth and projected, kept where the frame's depth lies within 1 cm of
them (the visible part); ``box`` is those pixels' bounding box, ``mask`` those pixels grown by 2 px. Printed per
object and prompt: ADD-S (mean distance from each ground-truth-posed model point to the nearest point of the model
posed by the SDK, mm), rotation and centre differences, ms, confidence, ``ambiguous``, fit and see-through shares;
and the annotation's own fit: the median distance from the depth points within 1 cm of the ground-truth-posed model
to it (mm). Where that is larger than the ADD-S to be checked, the frame cannot check it.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import cv2
import numpy as np
from scipy.spatial import cKDTree

from equipose import PoseEstimator

HERE = pathlib.Path(__file__).resolve().parent
DATA = HERE.parents[2] / "shared" / "data"
OBJECTS = {1: "003_cracker_box", 3: "005_tomato_soup_can", 6: "011_banana", 9: "035_power_drill"}   # cls_index
NEAR_M = 0.01               # a projected model point is visible where the depth lies within this of it


def visible_pixels(Y: np.ndarray, depth_m: np.ndarray, K: np.ndarray) -> tuple:
    """(rows, cols) of the posed model points ``Y`` [M, 3] (camera frame, m) that the frame sees: projected inside it
    and within ``NEAR_M`` of its depth there."""
    H, W = depth_m.shape
    u = np.rint(Y[:, 0] / Y[:, 2] * K[0, 0] + K[0, 2]).astype(int)
    v = np.rint(Y[:, 1] / Y[:, 2] * K[1, 1] + K[1, 2]).astype(int)
    ok = (Y[:, 2] > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    u, v, z = u[ok], v[ok], Y[ok, 2]
    seen = np.abs(depth_m[v, u] - z) < NEAR_M
    return v[seen], u[seen]


def add_s_mm(P: np.ndarray, R_gt, t_gt, R, t) -> float:
    """ADD-S in mm: mean over the ground-truth-posed points of the distance to the nearest estimate-posed point."""
    d, _ = cKDTree(P @ R.T + t).query(P @ R_gt.T + t_gt)
    return float(d.mean() * 1e3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(DATA))
    ap.add_argument("--seed-model", default="can-tabletop")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--json")
    a = ap.parse_args(argv)
    import scipy.io
    root = pathlib.Path(a.data)
    ex = root / "realsense_graspnet_example"
    meta = scipy.io.loadmat(str(ex / "meta.mat"))
    poses, cls = meta["poses"], meta["cls_indexes"].ravel()
    K = np.asarray(meta["intrinsic_matrix"], np.float64)
    depth = cv2.imread(str(ex / "depth.png"), cv2.IMREAD_UNCHANGED)             # uint16
    depth_m = depth.astype(np.float64) / float(np.ravel(meta["factor_depth"])[0])
    full = np.stack(np.nonzero(depth_m > 0), 1)                                # [Q, 2] valid pixels (row, col)
    rows = []
    print(f"{'object':20s} {'prompt':5s} {'ADD-S mm':>8s} {'rot°':>6s} {'centre mm':>9s} {'ms':>6s} {'conf':>5s} amb   "
          f"{'fit':>5s} {'seen':>5s}  annotation fit mm")
    for i, c in enumerate(cls):
        if int(c) not in OBJECTS:
            continue
        name = OBJECTS[int(c)]
        P = np.loadtxt(root / "ycb_posecnn" / "models" / name / "points.xyz")[:, :3]   # [M, 3] m, object frame
        R_gt, t_gt = poses[:3, :3, i].astype(np.float64), poses[:3, 3, i].astype(np.float64)
        Y = P @ R_gt.T + t_gt
        vr, vc = visible_pixels(Y, depth_m, K)
        if len(vr) < 20:
            print(f"{name:20s} skipped: {len(vr)} visible model points")
            continue
        mask = np.zeros(depth.shape, np.uint8)
        mask[vr, vc] = 1
        mask = cv2.dilate(mask, np.ones((5, 5), np.uint8)).astype(bool)         # the model points' pixels, grown
        box = (int(vc.min()), int(vr.min()), int(vc.max() - vc.min() + 1), int(vr.max() - vr.min() + 1))
        x0, y0, w, h = box
        near = full[(full[:, 1] >= x0 - 10) & (full[:, 1] < x0 + w + 10) & (full[:, 0] >= y0 - 10)
                    & (full[:, 0] < y0 + h + 10)]                                # [Q, 2] valid pixels around it
        pts = np.stack([(near[:, 1] - K[0, 2]) * depth_m[near[:, 0], near[:, 1]] / K[0, 0],
                        (near[:, 0] - K[1, 2]) * depth_m[near[:, 0], near[:, 1]] / K[1, 1],
                        depth_m[near[:, 0], near[:, 1]]], 1)                    # [Q, 3] m, the frame's points
        d_gt, _ = cKDTree(Y).query(pts, distance_upper_bound=NEAR_M)
        annotation_fit = float(np.median(d_gt[np.isfinite(d_gt)]) * 1e3)
        est = PoseEstimator(a.seed_model, model_points=P, threads=a.threads)
        for prompt, kw in (("box", {"box": box}), ("mask", {"mask": mask})):
            est.predict(depth, K, depth_unit="mm", **kw)                       # warm-up
            ms = []
            for _ in range(a.runs):
                t0 = time.perf_counter()
                r = est.predict(depth, K, depth_unit="mm", **kw)
                ms.append((time.perf_counter() - t0) * 1e3)
            rot = float(np.degrees(np.arccos(np.clip((np.trace(R_gt.T @ r.rotation) - 1) / 2, -1, 1))))
            row = {"object": name, "prompt": prompt, "add_s_mm": add_s_mm(P, R_gt, t_gt, r.rotation, r.translation),
                   "rot_deg": rot, "centre_mm": float(np.linalg.norm(r.translation - t_gt) * 1e3),
                   "ms": float(np.median(ms)), "confidence": float(r.confidence), "ambiguous": bool(r.ambiguous),
                   "model_fit": r.extras.get("model_fit"), "see_through": r.extras.get("see_through"),
                   "annotation_fit_mm": annotation_fit, "box": list(box)}
            rows.append(row)
            print(f"{name:20s} {prompt:5s} {row['add_s_mm']:8.1f} {rot:6.1f} {row['centre_mm']:9.1f} {row['ms']:6.1f} "
                  f"{row['confidence']:5.2f} {str(row['ambiguous']):5s} {row['model_fit']:5.2f} "
                  f"{row['see_through']:5.2f}  {annotation_fit:.1f}")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
