"""Distillation loss terms of a partial-view student checkpoint on its training views (no training step).

Usage: python tools/bench/distill_terms.py --state train/state/chair-partial [--checkpoint CKPT] [--batches 20]

Prints the mean over ``--batches`` batches (batch size and views from the state's config, fixed seed) of the terms
of ``equipose.train.losses.distillation_loss`` — ``shape`` (chamfer to the teacher's shape), ``pose``, ``reach``,
``view`` (the input points at the teacher pose against the student's shape), ``drift`` (the squared length of the
motion 10 ICP iterations of the view onto that shape make from the teacher pose) — and ``teacher_view`` /
``teacher_drift``: the same against the teacher's own shape, the references. Model units² (mean squared distances);
``drift_deg`` / ``teacher_drift_deg``: the mean rotation of that motion in degrees.
Needs the state's cached teacher targets (``teacher.npz``, written by the first training slice).
"""
from __future__ import annotations

import argparse
import pathlib

import numpy as np
import torch

from equipose.train.fitting.checkpoint import model_from_checkpoint
from equipose.train.data.datasets import collate
from equipose.train.fitting.losses import distillation_loss, icp_drift, view_distance
from equipose.train.fitting.config import TrainConfig
from equipose.train.fitting.trainer import _datasets


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--state", required=True, help="training-state folder (config.json, latest.pt, teacher.npz)")
    ap.add_argument("--checkpoint", help="student checkpoint to measure (default: the state's latest.pt)")
    ap.add_argument("--batches", type=int, default=20)
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    state = pathlib.Path(args.state)
    cfg = TrainConfig.from_sources(str(state / "config.json"))
    model, _ = model_from_checkpoint(args.checkpoint or str(state / "latest.pt"))
    model.eval()
    train_ds, _ = _datasets(cfg, model.num_points)
    z = np.load(state / "teacher.npz")
    rng = np.random.default_rng(0)
    sums: dict = {}
    with torch.no_grad():
        for _ in range(args.batches):
            idx = rng.integers(0, len(train_ds), cfg.batch_size)
            x = torch.from_numpy(collate([train_ds.sample(int(i), rng) for i in idx])["points"])   # [B, N, 3]
            S = torch.from_numpy(z["shapes"][z["instance"][idx]]).float()                         # [B, M, 3]
            R = torch.from_numpy(z["rotations"][idx]).float()                                     # [B, 3, 3]
            t = torch.from_numpy(z["translations"][idx]).float()                                  # [B, 3]
            out = model(x, return_aux=True)
            _, parts = distillation_loss(out, S, R, t, model.anchors, points=x, view_weight=1.0)
            parts["teacher_view"] = view_distance(x, R, t, S).item()                             # reference
            for name, shape in (("drift", out["canonical_shape"]), ("teacher_drift", S)):
                w = icp_drift(x, R, t, shape)                                                      # [B, 6]
                parts[name] = w.pow(2).sum(1).mean().item()                                       # the loss term
                parts[name + "_deg"] = np.degrees(w[:, :3].norm(dim=1).mean().item())
            for k, v in parts.items():
                sums[k] = sums.get(k, 0.0) + v / args.batches
    print("  ".join(f"{k} {v:.6f}" for k, v in sums.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
