"""Axis error of cylinder models on procedural closed cylinders of every proportion, rendered as tabletop depth.

Usage: python tools/bench/squat_tins.py [--models can-tabletop] [--count 40] [--views 3] [--seed 7]

Cylinders: radius 3–7 cm, height / diameter log-uniform in 0.25–4 (``equipose.train.shapes.cylinder_proportions``,
seeded apart from the training cylinders); views as the tabletop renderer draws them (0.5–1.4 m, rotations uniform).
Reported per model: median unsigned axis error (°), share within 5° / 10°, and the share of views whose axis is
≥ 45° off (the lying / upright confusion), split into squat (h/d < 1) and tall cylinders. The metadata
``shape_prior`` stage of a file can be switched off for comparison with ``--no-stages``.
"""
from __future__ import annotations

import argparse

import numpy as np


def render_cylinders(count: int, views: int, seed: int):
    """[(points [P, 3] metres camera frame, R, h/d)] of ``count`` procedural cylinders × ``views``."""
    from equipose.train.data.render import RenderSettings, render_views
    from equipose.train.data.shapes import cylinder_mesh, cylinder_proportions
    out = []
    rng = np.random.default_rng([seed, 1])
    for r, h in cylinder_proportions(count, seed=[seed, 2]):
        V, F = cylinder_mesh(r, h)
        radius = float(np.linalg.norm(V, axis=1).max())
        for _ in range(views):
            d = float(rng.uniform(0.5, 1.4))
            var = (0.12 * d / radius) ** 2
            settings = RenderSettings(distance=d / radius, offset_var=(var, var, (0.05 / radius) ** 2))
            for p, R, _ in render_views({"vertices": V, "faces": F}, rng, 1, settings, radius=radius):
                out.append((p, R, h / (2 * r)))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="+", default=["can-tabletop"])
    ap.add_argument("--count", type=int, default=40)
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--no-stages", action="store_true", help="drop the files' shape_prior stage")
    args = ap.parse_args(argv)
    from equipose import PoseEstimator
    from equipose.core.geometry import axis_angle_deg
    views = render_cylinders(args.count, args.views, args.seed)
    hd = np.array([v[2] for v in views])
    print(f"{len(views)} views of {args.count} cylinders ({np.mean(hd < 1):.0%} squat, h/d < 1)")
    print(f"{'model':28s} {'subset':7s} {'n':>4s} {'median°':>8s} {'≤5°':>5s} {'≤10°':>5s} {'≥45°':>5s}")
    for name in args.models:
        est = PoseEstimator(name, threads=1)
        if args.no_stages:
            est.metadata = {**est.metadata, "shape_prior": None}
        err = []
        for p, R, _ in views:
            res = est.predict_points(p)
            err.append(float(axis_angle_deg(res.rotation[:, 2], R[:, 2], unsigned=True)))
        err = np.array(err)
        label = name + (" (no stages)" if args.no_stages else "")
        for sub, m in (("all", np.ones_like(hd, bool)), ("squat", hd < 1), ("tall", hd >= 1)):
            e = err[m]
            print(f"{label:28s} {sub:7s} {len(e):4d} {np.median(e):8.1f} {np.mean(e <= 5):5.2f} {np.mean(e <= 10):5.2f} "
                  f"{np.mean(e >= 45):5.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
