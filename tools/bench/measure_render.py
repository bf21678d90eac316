"""Render + crop frames per second for each source kind (1024-point surfels, dense 10k surfels, OCRTOC mesh, YCB mesh).

Usage: python tools/bench/measure_render.py [--frames 20]. Prints frames/s of render_views (render + equipose.preprocess) and the
load average (the machine is shared).
"""
import argparse
import os
import time

import numpy as np

from equipose.train.data.modelnet import default_data_root, load_modelnet
from equipose.train.data.meshio import read_mesh, read_modelnet_txt
from equipose.train.data.render import CATEGORY_DISTANCE, RenderSettings, render_views, surfels_from_points

p = argparse.ArgumentParser()
p.add_argument("--frames", type=int, default=20)
a = p.parse_args()
root = default_data_root()
cases = []
cloud = load_modelnet(root, "airplane", "train", 1)[0][0].astype(np.float64)
cases.append(("modelnet 1024-pt surfels", dict(zip(("normals", "radii"), surfels_from_points(cloud)), points=cloud), 1.0,
              CATEGORY_DISTANCE["airplane"]))
pts, nrm = read_modelnet_txt(root / "modelnet40_normal_resampled_airplane" / "train" / "airplane_0001.txt.gz")
pts = (pts - pts.mean(0)) / np.linalg.norm(pts - pts.mean(0), axis=1).max()
cases.append(("modelnet dense 10k surfels", dict(zip(("normals", "radii"), surfels_from_points(pts, nrm)), points=pts),
              1.0, CATEGORY_DISTANCE["airplane"]))
for name, path in (("OCRTOC mug mesh", root / "ocrtoc_scanned_household/mug/visual.ply"),
                   ("YCB drill mesh", root / "ycb_meshes_pybullet/YcbPowerDrill/textured_simple_reoriented.obj")):
    V, F = read_mesh(path)
    V = V - V.mean(0)
    r = float(np.linalg.norm(V, axis=1).max())
    cases.append((f"{name} ({len(F)} tris)", {"vertices": V, "faces": F}, r, 0.6 / r))
for name, shape, radius, dist in cases:
    t0 = time.perf_counter()
    out = render_views(shape, np.random.default_rng(0), a.frames, RenderSettings(distance=dist), radius=radius)
    dt = time.perf_counter() - t0
    print(f"{name:34s} {len(out) / dt:6.1f} frames/s  ({np.mean([len(o[0]) for o in out]):.0f} pts/view kept)  "
          f"load avg {os.getloadavg()[0]:.1f}", flush=True)
