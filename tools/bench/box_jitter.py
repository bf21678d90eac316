"""A detector's box jitters from frame to frame: how much does the pose move with it? (labelled mOSD Kinect scenes)

Usage: python tools/bench/box_jitter.py [--models can-tabletop cup-tabletop bowl-tabletop] [--data DIR]
    [--shift 2] [--profile default] [--json FILE]
For every labelled object of every ``learn*.pcd`` (``box_vs_mask.objects``: the mask's bounding box), the box is moved
by (dx, dy) in {−shift, 0, +shift}² pixels, its size kept, and each of the 9 boxes runs through
``PoseEstimator.predict`` (no up prior). Per object: the median over the 9 poses of the centre's distance (mm) and of
the axis angle (degrees, sign-folded; symmetry axis, else the rotation's z column) from the median pose. Per model:
the median and mean of those per-object figures over the objects.
"""
from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from box_vs_mask import objects, read_scenes, scene_arguments  # noqa: E402

from equipose import PoseEstimator  # noqa: E402


def _axis(r) -> np.ndarray:
    a = r.symmetry_axis if r.symmetry_axis is not None else r.rotation[:, 2]
    return a if a[1] >= 0 else -a                                               # sign-folded


def spread(est, cloud: dict, box, shift: int) -> tuple:
    """(centre mm, axis degrees): median deviation of the poses of the shifted boxes from their median pose."""
    x, y, w, h = box
    T, A = [], []
    for dy in (-shift, 0, shift):
        for dx in (-shift, 0, shift):
            r = est.predict(cloud["depth"], cloud["K"], box=(x + dx, y + dy, w, h))
            T.append(r.translation)
            A.append(_axis(r))
    T, A = np.array(T), np.array(A)                                             # [9, 3], [9, 3]
    centre = np.linalg.norm(T - np.median(T, 0), axis=1) * 1e3                 # [9] mm
    mid = np.median(A, 0)
    mid /= np.linalg.norm(mid)
    angle = np.degrees(np.arccos(np.clip(np.abs(A @ mid), 0.0, 1.0)))          # [9] degrees
    return float(np.median(centre)), float(np.median(angle))


def main(argv=None) -> int:
    ap = scene_arguments(__doc__.splitlines()[0])
    ap.add_argument("--shift", type=int, default=2, help="pixels the box moves each way")
    a = ap.parse_args(argv)
    clouds = read_scenes(a.data)
    rows = []
    print(f"{'model':16s} {'objects':>7s} {'centre mm med':>13s} {'mean':>6s} {'axis° med':>9s} {'mean':>6s}")
    for model in a.models:
        est = PoseEstimator(model, profile=a.profile)
        mine = []
        for name, cloud in clouds.items():
            for oid, _, box in objects(cloud):
                c, ang = spread(est, cloud, box, a.shift)
                mine.append({"model": model, "scene": name, "object": oid, "centre_mm": c, "axis_deg": ang})
        ce, ax = np.array([r["centre_mm"] for r in mine]), np.array([r["axis_deg"] for r in mine])
        print(f"{model:16s} {len(mine):7d} {np.median(ce):13.2f} {ce.mean():6.2f} {np.median(ax):9.2f} {ax.mean():6.2f}")
        rows += mine
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
