"""The training options (``TrainConfig``) and their consistency checks.

Convention:
    Options come from defaults < a JSON file of field names (``--config``) < explicit values; ``check_config`` raises
    ``ConfigError`` for options that contradict each other or are out of range, before any data is read. Torch-free.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass

from equipose.core.errors import ConfigError

__all__ = ["TrainConfig", "check_config"]


@dataclass
class TrainConfig:
    """Every training option (the ``--config`` JSON uses these names)."""
    category: str = "airplane"
    mode: str = "complete"                # complete | partial
    preset: str = "small"
    steps: int = 1000
    out: str = "runs/train"
    batch_size: int = 8
    lr: float = 5e-4
    lr_gamma: float = 0.9995              # ExponentialLR per epoch (spec §5)
    val_every: int = 250
    ckpt_every: int = 100
    val_size: int = 50                    # fixed validation subset (test split, seeded rotations)
    calib_size: int = 64                  # category-frame training inputs for the validation-time calibration
    seed: int = 0
    threads: int = 1
    data_root: str = ""
    train_limit: int | None = None        # first K training instances only (tests, quick runs)
    views: int = 10                       # partial: rendered views per training instance
    test_views: int = 5                   # partial: rendered views per test instance
    cache_dir: str = ""
    device: str = ""                      # "" = cuda when present, else cpu
    init: str = ""                        # warm start: weights of this checkpoint (same preset and mode), fresh
                                          # optimiser and step 0 (e.g. a related category); ignored on --resume
    freeze: str = ""                      # comma-separated submodules kept fixed: blocks, pose_head, inv_head, decoder
    teacher: str = ""                     # partial only: distil from this complete-shape checkpoint (distill.py)
    teacher_refine: int = 5               # teacher's ICP re-scoring of its k best hypotheses (0 = plain network)
    teacher_priors: str = ""              # teacher's poses through frame priors, e.g. "footprint,mirror:x"
    teacher_flip: str = ""                # and through the flip stage of this model's flip_templates (name / .onnx)
    select_weight: float = 0.0            # distillation: weight of the hypothesis-selection cross-entropy
    shape_weight: float = 1.0             # distillation: weight of the canonical-shape chamfer to the teacher's shape
    view_weight: float = 0.0              # distillation: weight of the view's fit to that shape at the teacher pose
    cloud_weight: float = 0.0             # distillation: weight of the chamfer to the complete cloud, teacher frame
    drift_weight: float = 0.0             # distillation: weight of how far ICP of the view onto it leaves that pose
    drift_iters: int = 10                 # distillation: ICP iterations of that drift (losses.icp_drift)
    rotate_augment: bool = False          # distillation: views turned by random rotations (augment.rotate_views)
    symmetry_weight: float = 0.0          # complete, symmetric category: weight of model.axial_symmetry_loss
    minutes: float = 0.0                  # > 0: stop (validate, save) once training steps took this many minutes

    @classmethod
    def from_sources(cls, config_file=None, **overrides) -> "TrainConfig":
        """Defaults < JSON config file < explicit overrides (``None`` values are ignored)."""
        names = {f.name for f in dataclasses.fields(cls)}
        values = {}
        if config_file:
            with open(config_file) as f:
                loaded = json.load(f)
            unknown = set(loaded) - names
            if unknown:
                raise ConfigError(f"unknown training options in {config_file}: {sorted(unknown)}")
            values.update(loaded)
        values.update({k: v for k, v in overrides.items() if v is not None and k in names})
        cfg = cls(**values)
        check_config(cfg)
        return cfg


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
        raise ConfigError("--view-weight / --drift-weight / --cloud-weight weigh distillation terms: "
                          "give --teacher too")
    if cfg.drift_iters < 1 or min(cfg.view_weight, cfg.drift_weight, cfg.shape_weight, cfg.cloud_weight) < 0:
        raise ConfigError(f"drift_iters must be ≥ 1 and the loss weights ≥ 0, got drift_iters {cfg.drift_iters}, "
                          f"view_weight {cfg.view_weight}, drift_weight {cfg.drift_weight}, "
                          f"shape_weight {cfg.shape_weight}, cloud_weight {cfg.cloud_weight}")
