"""Instance-level mode on YCB-Video model points: rotation / translation error and time, next to ICP-60 from the same
observed points.

Each observation is one YCB object's points.xyz at a random pose 0.5–0.9 m in front of the camera, cut to the half that
faces the camera (a depth camera's view of a convex-ish object), with 2 mm noise. ICP-60: the same ICP (observation →
model, ``equipose.runtime.refine.icp_multi``) from the 60 icosahedral rotations, centroids aligned, best residual.

Usage: python tools/bench/instance_level.py [--model cup-tabletop] [--trials 20] [--k 10] [--objects a,b,...]
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np
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


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="cup-tabletop")
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--k", type=int, default=10)
    ap.add_argument("--objects", default=",".join(OBJECTS))
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    print(f"model {a.model}, instance_k {a.k}, {a.trials} random poses per object, camera-facing half + 2 mm noise")
    print("| object | ours rot median / mean ° | ours t median mm | ours ms | ICP-60 rot median / mean ° | ICP-60 t "
          "median mm | ICP-60 ms |")
    print("|---|---|---|---|---|---|---|")
    for name in a.objects.split(","):
        q = load_points(name)
        est = PoseEstimator(a.model, threads=1, model_points=q, instance_k=a.k)
        rows = {"ours": [], "icp": []}
        for _ in range(a.trials):
            obs, R, t = observe(q, rng)
            t0 = time.perf_counter()
            r = est.predict_points(obs)
            ms = (time.perf_counter() - t0) * 1e3
            rows["ours"].append((rot_err(r.rotation, R), np.linalg.norm(r.translation - t) * 1e3, ms))
            sub = q[:: max(1, len(q) // 1024)]
            t0 = time.perf_counter()
            Ri, ti = icp60(obs[:: max(1, len(obs) // 1024)], sub)
            ms = (time.perf_counter() - t0) * 1e3
            rows["icp"].append((rot_err(Ri, R), np.linalg.norm(ti - t) * 1e3, ms))
        o, i = np.array(rows["ours"]), np.array(rows["icp"])
        print(f"| {name} | {np.median(o[:, 0]):.2f} / {o[:, 0].mean():.2f} | {np.median(o[:, 1]):.1f} | "
              f"{np.median(o[:, 2]):.1f} | {np.median(i[:, 0]):.2f} / {i[:, 0].mean():.2f} | {np.median(i[:, 1]):.1f} | "
              f"{np.median(i[:, 2]):.1f} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
