"""Batched torch inference: hypothesis selection (argmin chamfer, spec §6) and the calibration offsets.

Convention:
    Input points [S, N, 3] float32 model units (FPS-ordered). Output R [S, 3, 3] (column-vector rotation), t [S, 3]
    model units, in the network's learned frame (apply ``calibration.apply_calibration`` for the category frame).
"""
from __future__ import annotations

import numpy as np
import torch

from equipose.train.evaluation.calibration import calibrate_offsets

__all__ = ["predict_torch", "calibrate_model"]


@torch.no_grad()
def predict_torch(model, points: np.ndarray, batch_size: int = 16, device="cpu") -> tuple:
    """(R [S, 3, 3], t [S, 3], score [S]) of the best of 60 hypotheses per input (lowest chamfer score)."""
    was_training = model.training
    model.eval()
    Rs, ts, ss = [], [], []
    for i in range(0, len(points), batch_size):
        x = torch.as_tensor(np.asarray(points[i:i + batch_size]), dtype=torch.float32, device=device)
        out = model(x)
        j = out["hypothesis_scores"].argmin(dim=1)                                   # [b]
        ar = torch.arange(len(j), device=device)
        Rs.append(out["hypothesis_rotations"][ar, j].cpu().numpy())
        ts.append(out["hypothesis_translations"][ar, j].cpu().numpy())
        ss.append(out["hypothesis_scores"][ar, j].cpu().numpy())
    model.train(was_training)
    return np.concatenate(Rs).astype(np.float64), np.concatenate(ts).astype(np.float64), np.concatenate(ss)


def calibrate_model(model, canonical_points: np.ndarray, symmetry: str = "none", unsigned_axis: bool = False,
                    batch_size: int = 16, device="cpu", seed: int = 0, rotations: np.ndarray | None = None) -> dict:
    """Calibration dict from category-frame inputs [K, N, 3] (model units): RANSAC over the selected poses.

    ``rotations`` [K, 3, 3] (optional): present input k rotated by R_k about the origin (x ↦ R_k x) and undo it on the
    prediction, δR_k = R_kᵀ R_pred, δt_k = R_kᵀ t_pred — the offsets then come from the same pose distribution as
    the test inputs instead of the single identity pose (the spec feeds identity-pose inputs only).
    """
    pts = np.asarray(canonical_points)
    if rotations is not None:
        pts = np.einsum("kij,knj->kni", rotations, pts)                               # [K, N, 3] rotated inputs
    dR, dt, _ = predict_torch(model, pts, batch_size, device)
    if rotations is not None:
        dR = np.einsum("kji,kjl->kil", rotations, dR)                                 # R_kᵀ R_pred
        dt = np.einsum("kji,kj->ki", rotations, dt)                                   # R_kᵀ t_pred
    return calibrate_offsets(dR, dt, symmetry=symmetry, unsigned_axis=unsigned_axis, seed=seed)
