"""Instance-level mode on YCB-Video model points: ADD-S, rotation / translation error and time, next to ICP-60 from
the same observed points.

Each observation is one YCB object's points.xyz at a random pose 0.5–0.9 m in front of the camera, cut to the half that
faces the camera (a depth camera's view of a convex-ish object), with 2 mm noise. ICP-60: the same ICP (observation →
model, ``equipose.runtime.refine.icp_multi``) from the 60 icosahedral rotations, centroids aligned, best residual.
ADD-S: the mean distance from each true posed model point to the nearest estimated posed one (mm); "≤ 3 mm" the share of
poses within 3 mm. Rotation errors are not symmetry-aware (the can's turn about its axis counts).

Usage: python tools/bench/instance_level.py [--model cup-tabletop] [--trials 20] [--k 10] [--objects a,b,...]
    [--seed 0] [--threads 1] [--no-icp60]
(v0.31 figures in docs/benchmarks.md: --model can-tabletop --trials 20 --seed 1 --threads 2 --no-icp60.)
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator
from equipose.core import icosahedral
from equipose.core.geometry import rotation_angle_deg
from equipose.runtime.refine import icp_multi

DATA = pathlib.Path(__file__).resolve().parents[3] / "shared" / "data" / "ycb_posecnn" / "models"
OBJECTS = ("003_cracker_box", "006_mustard_bottle", "035_power_drill", "025_mug", "021_bleach_cleanser",
           "011_banana")


def load_points(name: str) -> np.ndarray:
    return np.loadtxt(DATA / name / "points.xyz")[:, :3]


def observe(q: np.ndarray, rng) -> tuple:
    """(observed points [P, 3] m camera frame, R, t): random pose, the camera-facing half, 2 mm noise."""
    R = Rotation.random(random_state=rng).as_matrix()
    t = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(0.5, 0.9)])
    p = q @ R.T + t
    c = p.mean(0)
    view = c / np.linalg.norm(c)                                                # camera → object
    keep = (p - c) @ view < 0.0                                                 # the near half
    return p[keep] + rng.normal(scale=0.002, size=(int(keep.sum()), 3)), R, t


def rot_err(Ra, Rb) -> float:
    return float(rotation_angle_deg(Ra, Rb))


def icp60(obs: np.ndarray, q: np.ndarray, iters: int = 20) -> tuple:
    R0 = icosahedral.ANCHORS                                                    # [60, 3, 3]
    t0 = obs.mean(0) - np.einsum("aij,j->ai", R0, q.mean(0))
    R, t, res = icp_multi(obs, q, R0, t0, iters=iters)
    i = int(np.argmin(res))
    return R[i], t[i]


def add_s_mm(q: np.ndarray, R_est, t_est, R_true, t_true) -> float:
    """ADD-S (mm) of a pose estimate for model points ``q`` [M, 3] metres."""
    return float(cKDTree(q @ np.asarray(R_est).T + t_est).query(q @ R_true.T + t_true)[0].mean() * 1e3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="cup-tabletop")
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--k", type=int, default=10)
    ap.add_argument("--objects", default=",".join(OBJECTS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--no-icp60", dest="icp60", action="store_false", help="skip the ICP-60 baseline (slow)")
    a = ap.parse_args(argv)
    print(f"model {a.model}, instance_k {a.k}, {a.trials} random poses per object, camera-facing half + 2 mm noise, "
          f"{a.threads} thread(s)")
    print("| object | ours ADD-S median / mean mm | ours ≤ 3 mm | ours rot median / mean ° | ours t median mm | ours ms "
          "| ICP-60 ADD-S median mm | ICP-60 ≤ 3 mm | ICP-60 ms |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in a.objects.split(","):
        q = load_points(name)
        est = PoseEstimator(a.model, threads=a.threads, model_points=q, instance_k=a.k)
        rng = np.random.default_rng(a.seed)                                     # each object: the same poses per seed
        rows = {"ours": [], "icp": []}
        for _ in range(a.trials):
            obs, R, t = observe(q, rng)
            t0 = time.perf_counter()
            r = est.predict_points(obs)
            ms = (time.perf_counter() - t0) * 1e3
            rows["ours"].append((add_s_mm(q, r.rotation, r.translation, R, t), rot_err(r.rotation, R),
                                 np.linalg.norm(r.translation - t) * 1e3, ms))
            if a.icp60:
                sub = q[:: max(1, len(q) // 1024)]
                t0 = time.perf_counter()
                Ri, ti = icp60(obs[:: max(1, len(obs) // 1024)], sub)
                ms = (time.perf_counter() - t0) * 1e3
                rows["icp"].append((add_s_mm(q, Ri, ti, R, t), ms))
        o = np.array(rows["ours"])
        if rows["icp"]:
            i = np.array(rows["icp"])
            baseline = f"{np.median(i[:, 0]):.2f} | {np.mean(i[:, 0] <= 3.0):.2f} | {np.median(i[:, 1]):.1f}"
        else:
            baseline = "– | – | –"
        print(f"| {name} | {np.median(o[:, 0]):.2f} / {o[:, 0].mean():.2f} | {np.mean(o[:, 0] <= 3.0):.2f} | "
              f"{np.median(o[:, 1]):.2f} / {o[:, 1].mean():.2f} | {np.median(o[:, 2]):.1f} | {np.median(o[:, 3]):.1f} | "
              f"{baseline} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
