"""Experiment: does a visibility-aware two-sided score settle front/back flips of partial-view models?

Usage: python tools/bench/flip_visibility.py MODEL CATEGORY N   (e.g. car-partial car 200)

For N evenly spaced test views: the SDK's pose R and its partner turned 180° about the category up axis (z) are each
scored by (mean distance from the posed canonical shape's camera-visible points — nearest per 0.03 rad cell — to the
observed points) + (mean distance from the observed points to the posed canonical shape); the lower one is kept.
Prints flip rate (error > 150°), median error and 5° accuracy before / after, each score half alone, and whether the
score margin would make an informative ``ambiguous`` flag. Measured (2026-11-23): car-partial 200 views flip 0.53 →
0.49, median 168.9° → 122.9°, 5° 0.12 → 0.13 (margin not informative); sofa / chair unchanged; airplane 0.11 → 0.12.
Not shipped.
"""
import numpy as np, sys
from scipy.spatial import cKDTree
from equipose import PoseEstimator
from equipose.core.geometry import rotation_angle_deg as ang
from equipose.train.evaluation.evaluate import test_dataset
from equipose.core.handles import turn_about_z  # rotation about +z
name, cat, N = sys.argv[1], sys.argv[2], int(sys.argv[3])
ds = test_dataset("/work/shared/data", cat, "partial", 256, cache_dir="/work/main/data_cache")
S = [ds.raw(i) for i in np.linspace(0, len(ds) - 1, N).round().astype(int)]
est = PoseEstimator(name, threads=1)
def visible(X, cell=0.03):
    """indices of X [M,3] (camera frame, metres) nearest the camera per angular cell."""
    u = np.floor(X[:, 0] / X[:, 2] / cell).astype(int); v = np.floor(X[:, 1] / X[:, 2] / cell).astype(int)
    key = u * 100003 + v
    order = np.lexsort((X[:, 2], key))
    k = key[order]; first = np.r_[True, k[1:] != k[:-1]]
    vis = order[first]
    # keep points within 3 cm behind the front-most of their cell
    zmin = dict(zip(k[first], X[order[first], 2]))
    return np.array([i for i in range(len(X)) if X[i, 2] <= zmin[key[i]] + 0.03 * np.ptp(X[:, 2]) / 0.3])
def score(obs, canon, R, t):
    X = canon @ R.T + t
    vis = visible(X)
    d1 = cKDTree(obs).query(X[vis])[0].mean()
    d2 = cKDTree(X).query(obs)[0].mean()
    return d1 + d2, d1, d2
e0, e1, e2, e3, mg = [], [], [], [], []
for s in S:
    r = est.predict_points(s["points_m"])
    obs = s["points_m"]
    R, t = r.rotation, r.translation
    Rf = R @ turn_about_z(np.pi)
    a = score(obs, r.canonical_shape_object, R, t)
    b = score(obs, r.canonical_shape_object, Rf, t)
    Rg = s["rotation"]
    e0.append(ang(R, Rg)); e1.append(ang(Rf if b[0] < a[0] else R, Rg))
    mg.append(abs(a[0] - b[0]) / min(a[0], b[0]))
    e2.append(ang(Rf if b[1] < a[1] else R, Rg)); e3.append(ang(Rf if b[2] < a[2] else R, Rg))
e0, e1, e2, e3 = map(np.array, (e0, e1, e2, e3))
mg = np.array(mg)
for q in (0.05, 0.1, 0.2, 0.3):
    m = mg < q
    print(f"margin < {q}: {m.mean():.2f} of views, flip {np.mean(e1[m] > 150) if m.any() else -1:.2f} vs {np.mean(e1[~m] > 150) if (~m).any() else -1:.2f} otherwise")
for nm, e in (("vis-only", e2), ("obs-only", e3)):
    print(nm, f"flip {np.mean(e > 150):.2f} median {np.median(e):.1f} 5deg {np.mean(e < 5):.2f}")
print(f"{name}: n={len(e0)} flip before {np.mean(e0 > 150):.2f} after {np.mean(e1 > 150):.2f}; median {np.median(e0):.1f} -> {np.median(e1):.1f}; 5deg {np.mean(e0 < 5):.2f} -> {np.mean(e1 < 5):.2f}")
