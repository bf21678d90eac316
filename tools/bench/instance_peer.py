"""A generic peer for instance-level mode: Open3D FPFH features + RANSAC global registration + point-to-plane ICP from
the same model points, on the same observations as ``tools/bench/instance_level.py`` (the camera-facing half of a
YCB-Video object at a random pose, 2 mm noise; the same poses for the same ``--seed``). Prints ADD-S (mm), its
≤ 3 mm share and ms per object, next to equipose's instance-level mode when ``--model`` is given.

Open3D is not an equipose dependency: run this with it importable (``pip install open3d``).

Usage: python tools/bench/instance_peer.py [--trials 20] [--seed 1] [--voxel 0.005] [--objects a,b,...]
    [--icp-factor 1.0] [--model can-tabletop] [--threads 2]
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from instance_level import OBJECTS, add_s_mm, load_points, observe


def _features(points: np.ndarray, voxel: float):
    """(downsampled cloud with normals, its FPFH features) of ``points`` [P, 3] metres."""
    import open3d as o3d
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(voxel)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    fpfh = o3d.pipelines.registration.compute_fpfh_feature(
        cloud, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
    return cloud, fpfh


def peer_pose(model, observed: np.ndarray, voxel: float, seed: int = 0, icp_factor: float = 1.0) -> np.ndarray:
    """[4, 4] model → camera transform of the observation [P, 3] metres: FPFH + RANSAC, then point-to-plane ICP with
    pairs up to ``icp_factor`` × ``voxel`` apart. ``model``: (cloud, features) of the model points from ``_features``."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    src, src_f = model
    dst, dst_f = _features(observed, voxel)
    coarse = reg.registration_ransac_based_on_feature_matching(
        src, dst, src_f, dst_f, True, 1.5 * voxel, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * voxel)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    fine = reg.registration_icp(src, dst, icp_factor * voxel, coarse.transformation,
                                reg.TransformationEstimationPointToPlane())
    return np.asarray(fine.transformation)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--voxel", type=float, default=0.005, help="downsampling voxel (m); FPFH radius 5×, RANSAC 1.5×")
    ap.add_argument("--objects", default=",".join(OBJECTS))
    ap.add_argument("--icp-factor", type=float, default=1.0, help="ICP pair distance, × voxel")
    ap.add_argument("--model", help="also run equipose's instance-level mode with this seed network")
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args(argv)
    import open3d as o3d
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    print(f"{a.trials} random poses per object, camera-facing half + 2 mm noise, voxel {a.voxel * 1e3:g} mm")
    print("| object | peer ADD-S median / mean mm | peer ≤ 3 mm | peer ms | equipose ADD-S median / mean mm | "
          "equipose ≤ 3 mm | equipose ms |")
    print("|---|---|---|---|---|---|---|")
    for name in a.objects.split(","):
        q = load_points(name)
        model = _features(q, a.voxel)
        est = None
        if a.model:
            from equipose import PoseEstimator
            est = PoseEstimator(a.model, threads=a.threads, model_points=q)
        rng = np.random.default_rng(a.seed)                                     # the poses of instance_level.py
        peer, ours = [], []
        for i in range(a.trials):
            obs, R, t = observe(q, rng)
            t0 = time.perf_counter()
            T = peer_pose(model, obs, a.voxel, seed=i, icp_factor=a.icp_factor)
            peer.append((add_s_mm(q, T[:3, :3], T[:3, 3], R, t), (time.perf_counter() - t0) * 1e3))
            if est is not None:
                t0 = time.perf_counter()
                r = est.predict_points(obs)
                ours.append((add_s_mm(q, r.rotation, r.translation, R, t), (time.perf_counter() - t0) * 1e3))
        p = np.array(peer)
        row = f"| {name} | {np.median(p[:, 0]):.2f} / {p[:, 0].mean():.2f} | {np.mean(p[:, 0] <= 3):.2f} | " \
              f"{np.median(p[:, 1]):.1f} | "
        if ours:
            o = np.array(ours)
            row += f"{np.median(o[:, 0]):.2f} / {o[:, 0].mean():.2f} | {np.mean(o[:, 0] <= 3):.2f} | " \
                   f"{np.median(o[:, 1]):.1f} |"
        else:
            row += "– | – | – |"
        print(row, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
