"""A mug's handle while tracking: rendered orbits around a test mug on a table through ``PoseEstimator.track``.

    python tools/bench/track_handle.py [--model mug-tabletop] [--sequences 10] [--frames 60] [--step-deg 6]
        [--seed 3] [--up plane|none] [--no-hold]

Each sequence renders one mug-tabletop test shape standing on a table, the camera circling it at a fixed elevation
(20–45°) and distance (0.6–0.9 m) by ``--step-deg`` per frame (the depth-sensor model applied, no occluder), so its
handle turns out of view and back. Tracked with the visible mask as the region, it prints the median rotation error
(full 6D: the handle's azimuth counts) over the frames whose handle shows (at least 30 handle pixels in front) and
over those where it does not, and how many results called the handle seen. ``--no-hold`` tracks with
``hold_turns=False`` (no held handle azimuth).

Convention: angles in degrees, distances in metres.
"""
from __future__ import annotations

import argparse

import numpy as np

from equipose import PoseEstimator
from equipose.eval.metrics import rotation_errors
from equipose.sources.base import Frame
from equipose.train.data.render import camera_matrix, depth_to_uint16, splat_surfels
from equipose.train.data.scene import look_at_pose, table_surfels
from equipose.train.data.sensor import SensorModel, apply_sensor
from equipose.train.data.tabletop import tabletop_sources
from equipose.train.evaluation.confidence import handle_parts

HANDLE_PIXELS = 30          # a frame "shows" the handle with at least this many handle pixels in front


def orbit(shape: dict, handle: np.ndarray, rng, frames: int, step_deg: float, size=(640, 480)) -> tuple:
    """([Frame], [mask], [R object → camera], [handle pixels]) of a camera circling ``shape`` (surfels, metres,
    standing on z = its lowest point)."""
    K = camera_matrix(*size)
    pts, normals, radii = shape["points"], shape["normals"], shape["radii"]
    z_table = float(pts[:, 2].min())
    r = float(np.linalg.norm(pts, axis=1).max())
    tab = table_surfels(z_table, max(3.0 * r, 0.4), max(0.03 * r, 0.004))
    az0, el, dist = rng.uniform(0, 2 * np.pi), np.radians(rng.uniform(20.0, 45.0)), rng.uniform(0.6, 0.9)
    out, masks, Rs, shown = [], [], [], []
    for k in range(frames):
        R, t = look_at_pose(az0 + np.radians(step_deg * k), el, dist)
        d_obj = splat_surfels(pts @ R.T + t, normals @ R.T, radii, K, size)
        d_tab = splat_surfels(tab["points"] @ R.T + t, tab["normals"] @ R.T, tab["radii"], K, size)
        d_part = splat_surfels(pts[handle] @ R.T + t, normals[handle] @ R.T, radii[handle], K, size)
        d = np.minimum(d_obj, d_tab)
        mask = np.isfinite(d_obj) & (d_obj <= d_tab)
        shown.append(int(np.count_nonzero(np.isfinite(d_part) & (d_part <= d + 0.002))))
        depth, _ = depth_to_uint16(np.where(np.isfinite(d), apply_sensor(d, rng, SensorModel()), np.inf))
        out.append(Frame(depth=depth, K=K, index=k))
        masks.append(mask & (depth > 0))
        Rs.append(R)
    return out, masks, Rs, shown


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="mug-tabletop")
    ap.add_argument("--sequences", type=int, default=10)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--step-deg", dest="step_deg", type=float, default=6.0)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--up", choices=("plane", "none"), default="plane")
    ap.add_argument("--no-hold", dest="hold", action="store_false", help="track with hold_turns=False")
    ap.add_argument("--data-root", dest="data_root")
    a = ap.parse_args(argv)
    from equipose.train.data.modelnet import default_data_root
    est = PoseEstimator(a.model)
    sources = tabletop_sources(a.data_root or default_data_root(), est.category, "test")
    parts = handle_parts(est, sources)
    rng = np.random.default_rng(a.seed)
    err_shown, err_hidden, called = [], [], 0
    for _ in range(a.sequences):
        s = int(rng.integers(len(sources)))
        frames, masks, Rs, shown = orbit(sources[s][1], parts[s], rng, a.frames, a.step_deg)
        records = est.track(iter(frames), regions=lambda f: [{"box": None, "mask": masks[f.index]}],
                            up=None if a.up == "none" else "plane", hold_turns=a.hold)
        for k, rec in enumerate(records):
            if not rec.poses:
                continue
            e = float(rotation_errors(rec.poses[0].rotation[None], Rs[k][None])[0])
            (err_shown if shown[k] >= HANDLE_PIXELS else err_hidden).append(e)
            called += bool(rec.poses[0].handle_visible)
    n = len(err_shown) + len(err_hidden)

    def med(v):
        return f"{np.median(v):.1f}° (≤ 20°: {np.mean(np.array(v) <= 20):.2f})" if v else "-"
    print(f"{a.model} ({'hold' if a.hold else 'no hold'}, up={a.up}): {n} frames of {a.sequences} orbits; handle "
          f"shown on {len(err_shown)}, hidden on {len(err_hidden)}, called seen on {called}; rotation error median: "
          f"shown {med(err_shown)}, hidden {med(err_hidden)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
