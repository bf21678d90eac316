"""Pose-error metrics of the paper's tables (spec §6) plus flip rate.

Convention:
    R_pred, R_gt [S, 3, 3] act on column vectors (x = R x_obj + t); t_pred, t_gt [S, 3] in any one unit; ``t_norm``
    [S] (or scalar) divides translation errors (ModelNet: the instance's bbox diagonal, as the paper; metric data: 1,
    so errors are metres and 0.05 means 5 cm).
    Asymmetric categories: geodesic angle acos((tr(R̂ R_gtᵀ) − 1) / 2) in degrees.
    ``continuous:<axis>``: angle between R̂ e_axis and R_gt e_axis; ``unsigned_axis`` (cans: up ≡ down) folds it to
    min(θ, 180° − θ).
"""
from __future__ import annotations

import numpy as np

from equipose.errors import ConfigError
from equipose.geometry import axis_angle_deg, rotation_angle_deg

__all__ = ["rotation_errors", "translation_errors", "summarize", "FLIP_DEG", "ROW_KEYS"]

FLIP_DEG = 150.0
ROW_KEYS = ("method", "rot_mean_deg", "rot_median_deg", "trans_mean", "trans_median", "acc_5deg", "acc_5deg_005",
            "flip_rate")
_AXES = {"x": 0, "y": 1, "z": 2}


def rotation_errors(R_pred, R_gt, symmetry: str = "none", unsigned_axis: bool = False) -> np.ndarray:
    """Rotation errors [S] in degrees."""
    R_pred, R_gt = np.asarray(R_pred, np.float64), np.asarray(R_gt, np.float64)
    if R_pred.shape != R_gt.shape or R_pred.shape[-2:] != (3, 3):
        raise ConfigError(f"rotation arrays must both be [S, 3, 3], got {R_pred.shape} and {R_gt.shape}")
    if symmetry == "none":
        return rotation_angle_deg(R_pred, R_gt)
    if symmetry.startswith("continuous:") and symmetry[-1] in _AXES:
        a = _AXES[symmetry[-1]]
        return axis_angle_deg(R_pred[..., :, a], R_gt[..., :, a], unsigned=unsigned_axis)
    raise ConfigError(f"unsupported symmetry {symmetry!r}")


def translation_errors(t_pred, t_gt, t_norm=1.0) -> np.ndarray:
    """‖t̂ − t‖ / t_norm, [S]."""
    return np.linalg.norm(np.asarray(t_pred, np.float64) - np.asarray(t_gt, np.float64), axis=-1) / np.asarray(t_norm)


def summarize(method: str, rot_err, trans_err) -> dict:
    """One table row: mean/median errors, 5° and 5°+0.05 accuracies, flip rate (rotation error > 150°)."""
    r, t = np.asarray(rot_err, np.float64), np.asarray(trans_err, np.float64)
    if r.size == 0:
        raise ConfigError("no samples to summarise")
    return {"method": method, "rot_mean_deg": float(r.mean()), "rot_median_deg": float(np.median(r)),
            "trans_mean": float(t.mean()), "trans_median": float(np.median(t)),
            "acc_5deg": float(np.mean(r <= 5.0)), "acc_5deg_005": float(np.mean((r <= 5.0) & (t <= 0.05))),
            "flip_rate": float(np.mean(r > FLIP_DEG))}
