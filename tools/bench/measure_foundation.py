"""Foundation figures: params, MACs and torch-eager forward ms (median of 20) per preset at 1024 and 512 points,
plus the largest equivariance error over all 60 rotations. Usage: python tools/bench/measure_foundation.py"""
import statistics
import time

import numpy as np
import torch

from equipose.core.presets import count_params, get_preset, total_macs
from equipose.testing import equivariance_errors, torch_model_fn
from equipose.train import EquiPoseNet

torch.manual_seed(0)
rng = np.random.default_rng(0)
print(f"torch {torch.__version__}, threads {torch.get_num_threads()}")
for name in ("tiny", "small", "paper"):
    for n in (1024, 512):
        cfg = get_preset(name).replace(num_points=n, num_canonical_points=n)
        model = EquiPoseNet(cfg, partial=True).eval()
        x = torch.tensor(rng.normal(size=(1, n, 3)) * 0.2, dtype=torch.float32)
        with torch.no_grad():
            for _ in range(2):
                model(x)
            ts = []
            for _ in range(20):
                t = time.perf_counter()
                model(x)
                ts.append((time.perf_counter() - t) * 1e3)
        print(f"{name:6s} N={n:5d} params {count_params(cfg):>10,} GMAC {total_macs(cfg) / 1e9:6.2f} "
              f"forward ms p50 {statistics.median(ts):8.1f}", flush=True)
worst = 0.0
for name in ("tiny", "small", "paper"):
    for partial in (True, False):
        model = EquiPoseNet(name, partial=partial)
        n = model.num_points
        x = (rng.normal(size=(1, n, 3)) * [0.25, 0.15, 0.1]).astype(np.float32)
        errs = equivariance_errors(torch_model_fn(model), x, rotations=None if name != "paper" else range(0, 60, 6))
        worst = max(worst, errs["max"])
        print(f"equivariance {name} partial={partial}: max abs error {errs['max']:.2e}", flush=True)
print(f"largest equivariance error: {worst:.2e}")
