"""Seconds per training step (forward + backward + Adam) on CPU per preset, on real ModelNet airplane batches.

Usage: python tools/bench/measure_train_step.py [--presets tiny small paper] [--batch 8 8 4] [--steps 3] [--threads 1]
Prints one line per preset: median s/step over ``--steps`` timed steps after one warm-up, plus the load average
(the machine is shared: figures are only comparable at similar load).
"""
import argparse
import os
import statistics
import time

import numpy as np
import torch

from equipose.train.data.datasets import ModelNetComplete, collate
from equipose.train.data.modelnet import default_data_root
from equipose.train.fitting.losses import chamfer_min_of_60_loss
from equipose.train.network.model import EquiPoseNet

p = argparse.ArgumentParser()
p.add_argument("--presets", nargs="+", default=["tiny", "small", "paper"])
p.add_argument("--batch", nargs="+", type=int, default=[8, 8, 4])
p.add_argument("--steps", type=int, default=3)
p.add_argument("--threads", type=int, default=1)
p.add_argument("--mode", default="partial", choices=["partial", "complete"])
a = p.parse_args()
torch.set_num_threads(a.threads)
rng = np.random.default_rng(0)
print(f"torch {torch.__version__}, threads {a.threads}, mode {a.mode}")
for name, B in zip(a.presets, a.batch):
    model = EquiPoseNet(name, partial=a.mode == "partial")
    ds = ModelNetComplete(default_data_root(), "airplane", "train", model.num_points, train=True, limit=64)
    opt = torch.optim.Adam(model.parameters(), lr=5e-4)
    times = []
    for s in range(a.steps + 1):
        batch = collate([ds.sample(int(i), rng) for i in rng.integers(0, len(ds), B)])
        t0 = time.perf_counter()
        loss = chamfer_min_of_60_loss(model(torch.from_numpy(batch["points"]), return_aux=True))
        opt.zero_grad()
        loss.backward()
        opt.step()
        if s:
            times.append(time.perf_counter() - t0)
    print(f"{name:6s} batch {B:2d}  N {model.num_points:4d}  s/step median {statistics.median(times):7.2f} "
          f"(min {min(times):.2f}, max {max(times):.2f})  load avg {os.getloadavg()[0]:.1f}", flush=True)
