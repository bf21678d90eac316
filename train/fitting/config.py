"""The training options (``TrainConfig``) and their consistency checks.

Convention:
    Options come from defaults < a JSON file of field names (``--config``) < explicit values; ``check_config`` raises
    ``ConfigError`` for options that contradict each other or are out of range, before any data is read. Torch-free.
"""
from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field

from equipose.core.errors import ConfigError

__all__ = ["TrainConfig", "check_config"]


def _opt(default, text: str, **meta):
    """A ``TrainConfig`` field whose ``equipose train --field-name`` flag has this help (``{presets}``: the preset
    names) and, in ``meta``, e.g. ``choices``."""
    return field(default=default, metadata={"help": text, **meta})


@dataclass
class TrainConfig:
    """Every training option. The ``--config`` JSON uses these names, and ``equipose train`` has one flag per field
    (``batch_size`` → ``--batch-size``; type from the annotation, help from the field's metadata)."""
    category: str = _opt("airplane", "ModelNet40 or tabletop category")
    mode: str = _opt("complete", "complete clouds or rendered partial depth", choices=("complete", "partial"))
    preset: str = _opt("small", "model preset: one of {presets} ('edge' is the deployment preset)")
    steps: int = _opt(1000, "optimisation steps in total (a resumed run continues to this)")
    out: str = _opt("runs/train", "output folder (latest.pt, log.jsonl, config.json)")
    batch_size: int = _opt(8, "samples per step and process")
    lr: float = _opt(5e-4, "Adam learning rate (the paper's)")
    lr_gamma: float = _opt(0.9995, "learning-rate factor per epoch (ExponentialLR, spec §5)")
    val_every: int = _opt(250, "steps between validations")
    ckpt_every: int = _opt(100, "steps between checkpoints")
    val_size: int = _opt(50, "validation subset size (test split, seeded rotations)")
    calib_size: int = _opt(64, "category-frame training inputs of the validation-time calibration")
    seed: int = _opt(0, "random seed")
    threads: int = _opt(1, "torch CPU threads")
    data_root: str = _opt("", "shared data folder (default $EQUIPOSE_DATA, else ../shared/data)")
    train_limit: int | None = _opt(None, "use only the first K training instances (tests, quick runs)")
    views: int = _opt(10, "partial: rendered views per training instance")
    test_views: int = _opt(5, "partial: rendered views per test instance")
    cache_dir: str = _opt("", "partial: render cache folder (default data_cache/)")
    sensor: bool = _opt(False, "partial, tabletop categories: training views through a depth-sensor model (noise "
                               "growing with z², flying pixels and holes at edges, quantisation) with an occluder "
                               "in front of part of the object in half of them (validation views stay clean)")
    device: str = _opt("", "cpu | cuda | cuda:K (default: cuda when present, else cpu)")
    init: str = _opt("", "warm start from this checkpoint's weights (same preset and mode; fresh optimiser, step 0), "
                         "e.g. a trained related category; ignored on --resume")
    freeze: str = _opt("", "comma-separated submodules kept fixed (blocks, pose_head, inv_head, decoder), e.g. "
                           "'decoder' when fine-tuning a complete model on partial views")
    teacher: str = _opt("", "partial mode: distil from this complete-shape checkpoint of the same category (its pose "
                            "and canonical shape on the complete cloud of each rendered view; no pose labels), or "
                            "from a partial-view checkpoint (its consensus pose over each instance's clean rendered "
                            "views, e.g. to fine-tune a model on --sensor views)")
    teacher_refine: int = _opt(5, "teacher's ICP re-scoring of its k best hypotheses (0 = plain network)")
    teacher_priors: str = _opt("", "distillation: pass the teacher's poses through these frame priors (mirror plane / "
                                   "footprint of each complete training cloud, equipose.runtime.frame_priors), e.g. "
                                   "'footprint,mirror:x'")
    teacher_flip: str = _opt("", "distillation: settle the teacher's half-turn flips with the flip stage of this "
                                 "model's flip_templates metadata (a shipped name or .onnx, e.g. airplane-complete)")
    select_weight: float = _opt(0.0, "distillation: weight of the cross-entropy that makes the student's own score "
                                     "pick the best hypothesis")
    shape_weight: float = _opt(1.0, "distillation: weight of the chamfer between the student's canonical shape and "
                                    "the teacher's (the SDK's ICP re-scoring fits the view to that shape)")
    view_weight: float = _opt(0.0, "distillation: weight of the observed points' distance to the student's "
                                   "canonical shape at the teacher's pose (where the view lies is what ICP "
                                   "re-scoring fits)")
    cloud_weight: float = _opt(0.0, "distillation: weight of the chamfer between the student's canonical shape and "
                                    "the complete training cloud carried into the teacher's frame by its pose")
    drift_weight: float = _opt(0.0, "distillation: weight of how far --drift-iters ICP iterations of the view onto "
                                    "the student's canonical shape move from the teacher's pose (asks that pose to "
                                    "be where the SDK's ICP re-scoring settles)")
    drift_iters: int = _opt(10, "distillation: ICP iterations of the drift term (losses.icp_drift)")
    rotate_augment: bool = _opt(False, "distillation: turn each training view about its centroid by a uniform random "
                                       "rotation (its teacher pose with it), beyond the 60 rotations the network is "
                                       "exactly equivariant to")
    symmetry_weight: float = _opt(0.0, "complete mode, rotationally symmetric category: weight of the loss that "
                                       "keeps the predicted canonical shape symmetric about its z axis, so that z is "
                                       "every instance's symmetry axis rather than its longest direction")
    minutes: float = _opt(0.0, "wall-clock budget: stop (validate, save) once this invocation's training steps took "
                               "this many minutes, validation excluded; --steps still caps it (0 = no budget)")

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
