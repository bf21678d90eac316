"""Consistency checks of a ``TrainConfig`` (``equipose.train.trainer``): options that contradict each other or are
out of range raise ``ConfigError`` before any data is read."""
from __future__ import annotations

from equipose.core.errors import ConfigError

__all__ = ["check_config"]


def check_config(cfg) -> None:
    """Raise ``ConfigError`` naming the offending options of a ``TrainConfig``."""
    if cfg.mode not in ("complete", "partial"):
        raise ConfigError(f"mode must be complete or partial, got {cfg.mode!r}")
    if cfg.teacher and cfg.mode != "partial":
        raise ConfigError("--teacher distils a partial-view model: use it with --mode partial")
    if (cfg.teacher_priors or cfg.teacher_flip) and not cfg.teacher:   # (the steps are checked by distill)
        raise ConfigError("--teacher-priors / --teacher-flip apply to the teacher's poses: give --teacher too")
    if cfg.batch_size < 1 or cfg.steps < 0:
        raise ConfigError("batch_size must be ≥ 1 and steps ≥ 0")
    if (cfg.view_weight or cfg.drift_weight or cfg.cloud_weight) and not cfg.teacher:
        raise ConfigError("--view-weight / --drift-weight / --cloud-weight weigh distillation terms: give --teacher too")
    if cfg.drift_iters < 1 or min(cfg.view_weight, cfg.drift_weight, cfg.shape_weight, cfg.cloud_weight) < 0:
        raise ConfigError(f"drift_iters must be ≥ 1 and the loss weights ≥ 0, got drift_iters {cfg.drift_iters}, "
                          f"view_weight {cfg.view_weight}, drift_weight {cfg.drift_weight}, "
                          f"shape_weight {cfg.shape_weight}, cloud_weight {cfg.cloud_weight}")
