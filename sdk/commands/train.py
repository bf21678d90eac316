"""``equipose train``: self-supervised training on complete ModelNet clouds or rendered partial depth.

Convention:
    Options come from defaults < ``--config F`` (JSON, ``TrainConfig`` field names) < explicit flags.
    Multi-process / multi-GPU: ``torchrun --standalone --nproc_per_node K -m equipose.cli train ...``
    (gloo on CPU, nccl on CUDA; ``--batch-size`` is per process).
"""
from __future__ import annotations

import pathlib

from equipose.core.presets import list_presets


def add_arguments(p) -> None:
    p.add_argument("--category", help="ModelNet40 category (default airplane)")
    p.add_argument("--mode", choices=["complete", "partial"], help="complete clouds or rendered partial depth")
    p.add_argument("--preset", help=f"model preset: one of {', '.join(list_presets())} (default small; 'edge' is the "
                                    "deployment preset)")
    p.add_argument("--steps", type=int, help="optimisation steps in total (a resumed run continues to this)")
    p.add_argument("--out", help="output folder (latest.pt, log.jsonl, config.json)")
    p.add_argument("--config", help="JSON file of TrainConfig options")
    p.add_argument("--resume", action="store_true", help="continue from OUT/latest.pt (weights, optimiser, step); "
                   "options default to OUT/config.json when no --config is given (e.g. --out train/state/car-complete)")
    p.add_argument("--batch-size", dest="batch_size", type=int, help="samples per step and process (default 8)")
    p.add_argument("--lr", type=float, help="Adam learning rate (default 5e-4, as the paper)")
    p.add_argument("--data-root", dest="data_root", help="shared data folder (default $EQUIPOSE_DATA or ../shared/data)")
    p.add_argument("--val-every", dest="val_every", type=int, help="steps between validations (default 250)")
    p.add_argument("--ckpt-every", dest="ckpt_every", type=int, help="steps between checkpoints (default 100)")
    p.add_argument("--val-size", dest="val_size", type=int, help="validation subset size (default 50)")
    p.add_argument("--train-limit", dest="train_limit", type=int, help="use only the first K training instances")
    p.add_argument("--views", type=int, help="partial: rendered views per training instance (default 10)")
    p.add_argument("--cache-dir", dest="cache_dir", help="partial: render cache folder (default data_cache/)")
    p.add_argument("--threads", type=int, help="torch CPU threads (default 1)")
    p.add_argument("--seed", type=int, help="random seed (default 0)")
    p.add_argument("--device", help="cpu | cuda | cuda:K (default: cuda when present)")
    p.add_argument("--freeze", help="comma-separated submodules kept fixed (blocks, pose_head, inv_head, decoder), "
                                    "e.g. 'decoder' when fine-tuning a complete model on partial views")
    p.add_argument("--teacher", help="partial mode: distil from this complete-shape checkpoint of the same category "
                   "(its pose and canonical shape on the complete cloud of each rendered view; no pose labels)")
    p.add_argument("--teacher-refine", dest="teacher_refine", type=int,
                   help="teacher's ICP re-scoring of its k best hypotheses (default 5; 0 = plain network)")
    p.add_argument("--teacher-priors", dest="teacher_priors",
                   help="distillation: pass the teacher's poses through these frame priors (mirror plane / footprint "
                   "of each complete training cloud, equipose.runtime.frame_priors), e.g. 'footprint,mirror:x'")
    p.add_argument("--teacher-flip", dest="teacher_flip",
                   help="distillation: settle the teacher's half-turn flips with the flip stage of this model's "
                   "flip_templates metadata (a shipped name or .onnx, e.g. airplane-complete)")
    p.add_argument("--select-weight", dest="select_weight", type=float,
                   help="distillation: weight of the cross-entropy that makes the student's own score pick the best "
                   "hypothesis (default 0)")
    p.add_argument("--shape-weight", dest="shape_weight", type=float,
                   help="distillation: weight of the chamfer between the student's canonical shape and the teacher's "
                   "(default 1; the SDK's ICP re-scoring fits the view to that shape)")
    p.add_argument("--view-weight", dest="view_weight", type=float,
                   help="distillation: weight of the observed points' distance to the student's canonical shape at "
                   "the teacher's pose (default 0; where the view lies is what ICP re-scoring fits)")
    p.add_argument("--cloud-weight", dest="cloud_weight", type=float,
                   help="distillation: weight of the chamfer between the student's canonical shape and the complete "
                   "training cloud carried into the teacher's frame by the teacher's pose (default 0)")
    p.add_argument("--drift-weight", dest="drift_weight", type=float,
                   help="distillation: weight of how far --drift-iters ICP iterations of the view onto the student's "
                   "canonical shape move from the teacher's pose (default 0; asks that pose to be where the SDK's "
                   "ICP re-scoring settles)")
    p.add_argument("--drift-iters", dest="drift_iters", type=int,
                   help="distillation: ICP iterations of the drift term (default 10)")
    p.add_argument("--rotate-augment", dest="rotate_augment", action="store_true", default=None,
                   help="distillation: turn each training view about its centroid by a uniform random rotation (its "
                   "teacher pose with it), beyond the 60 rotations the network is exactly equivariant to")
    p.add_argument("--symmetry-weight", dest="symmetry_weight", type=float,
                   help="complete mode, rotationally symmetric category: weight of the loss that keeps the predicted "
                   "canonical shape symmetric about its z axis, so that z is every instance's symmetry axis rather "
                   "than its longest direction (default 0; no labels involved)")
    p.add_argument("--minutes", type=float,
                   help="wall-clock budget: stop (validate, save) once this invocation's training steps took this many "
                   "minutes, validation excluded; --steps still caps it (equal-budget comparisons of presets)")
    p.add_argument("--init", help="warm start from this checkpoint's weights (same preset and mode; fresh optimiser, "
                                  "step 0), e.g. a trained related category")


def run(args) -> int:
    from equipose.train.fitting.config import TrainConfig
    from equipose.train.fitting.trainer import train
    opts = {k: v for k, v in vars(args).items() if k not in ("config", "resume")}
    config = args.config
    if args.resume and not config and args.out and (pathlib.Path(args.out) / "config.json").is_file():
        config = str(pathlib.Path(args.out) / "config.json")            # continue a run with its own options
    cfg = TrainConfig.from_sources(config, **opts)
    path = train(cfg, resume=args.resume)
    print(f"checkpoint: {path}")
    return 0
