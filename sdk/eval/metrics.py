"""Pose-error metrics of the paper's tables (spec §6) plus flip rate.

Convention:
    R_pred, R_gt [S, 3, 3] act on column vectors (x = R x_obj + t); t_pred, t_gt [S, 3] in any one unit; ``t_norm``
    [S] (or scalar) divides translation errors (ModelNet: the instance's bbox diagonal, as the paper; metric data: 1,
    so errors are metres and 0.05 means 5 cm).
    Asymmetric categories: geodesic angle acos((tr(R̂ R_gtᵀ) − 1) / 2) in degrees.
    ``continuous:<axis>``: angle between R̂ e_axis and R_gt e_axis; ``unsigned_axis`` (cans: up ≡ down) folds it to
    min(θ, 180° − θ).
    A table row is ``{"method": name, <metric>: float, ...}`` over the registered metrics (``register_metric``), in
    registration order; ``row_keys()`` (and ``ROW_KEYS``) list its keys. A new metric is one registered function.
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import ConfigError
from equipose.core.geometry import axis_angle_deg, rotation_angle_deg

__all__ = ["auroc", "rotation_errors", "translation_errors", "summarize", "FLIP_DEG", "ROW_KEYS", "METRICS",
           "register_metric", "unregister_metric", "row_keys"]

FLIP_DEG = 150.0
_AXES = {"x": 0, "y": 1, "z": 2}
METRICS: dict = {}     # name → fn(rot_err [S] degrees, trans_err [S]) -> float, in row order


def register_metric(name: str):
    """Decorator: add ``fn(rot_err, trans_err) -> float`` as the table column ``name`` (every ``summarize`` row)."""
    def deco(fn):
        if name == "method":
            raise ConfigError("'method' is the row's name, not a metric")
        METRICS[name] = fn
        return fn
    return deco


def unregister_metric(name: str) -> None:
    """Remove a registered metric (no error if absent)."""
    METRICS.pop(name, None)


def row_keys() -> tuple:
    """The keys of a ``summarize`` row: ``"method"`` then every registered metric."""
    return ("method",) + tuple(METRICS)


def __getattr__(name):
    if name == "ROW_KEYS":                                                      # always the current registry
        return row_keys()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


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


register_metric("rot_mean_deg")(lambda r, t: float(r.mean()))
register_metric("rot_median_deg")(lambda r, t: float(np.median(r)))
register_metric("trans_mean")(lambda r, t: float(t.mean()))
register_metric("trans_median")(lambda r, t: float(np.median(t)))
register_metric("acc_5deg")(lambda r, t: float(np.mean(r <= 5.0)))
register_metric("acc_5deg_005")(lambda r, t: float(np.mean((r <= 5.0) & (t <= 0.05))))
register_metric("flip_rate")(lambda r, t: float(np.mean(r > FLIP_DEG)))             # rotation error > 150°


def summarize(method: str, rot_err, trans_err) -> dict:
    """One table row: every registered metric of the errors — by default mean/median errors, 5° and 5°+0.05
    accuracies, flip rate. Convention: ``rot_err`` [S] degrees, ``trans_err`` [S] (see the module docstring)."""
    r, t = np.asarray(rot_err, np.float64), np.asarray(trans_err, np.float64)
    if r.size == 0:
        raise ConfigError("no samples to summarise")
    return {"method": method, **{name: float(fn(r, t)) for name, fn in METRICS.items()}}


def auroc(score: np.ndarray, y: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` for y = 1 (ties count half); NaN when one class is missing."""
    y = np.asarray(y, bool)
    n1, n0 = int(y.sum()), int((~y).sum())
    if not n1 or not n0:
        return float("nan")
    from scipy.stats import rankdata
    ranks = rankdata(score)
    return float((ranks[y].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))
