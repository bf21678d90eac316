"""``equipose calibrate``: RANSAC frame calibration of a trained checkpoint (spec §6), stored in the checkpoint.

Convention: inputs are training samples already in the category frame (complete: the clouds as aligned in the data;
partial: the rendered views mapped back by their render pose) — the category frame is the only label used. The
selected hypotheses on them are the offsets (δR, δt); their RANSAC consensus (5°, 0.025 model units, refit on
inliers) is written to ``checkpoint["calibration"]``. Symmetric categories (bottle, bowl, cup, can) calibrate the up
axis (z) only.
"""
from __future__ import annotations

import pathlib

import numpy as np

from equipose.core.errors import ConfigError


def add_arguments(p) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", help="checkpoint to calibrate (updated in place unless --out)")
    src.add_argument("--model", help="exported .onnx model: calibrate it for ICP re-scoring (--refine K) and store the "
                                     "result in its 'refine_calibration' metadata (PoseEstimator(refine='auto') uses it)")
    p.add_argument("--refine", type=int, default=5, help="with --model: hypotheses refined by ICP (default 5)")
    p.add_argument("--refine-iters", dest="refine_iters", type=int, default=10, help="with --model: ICP iterations")
    p.add_argument("--copies", type=int, default=1,
                   help="with --model: rotated input copies per object (PoseEstimator(copies=K); default 1 = off)")
    p.add_argument("--polish", type=int, default=0,
                   help="--model: ICP iterations on the pose the re-scoring selected, on all the object's points "
                   "(equipose.runtime.refine; default 0; sofa-partial ships with 30); the calibration runs with them")
    p.add_argument("--densify", type=int, default=0,
                   help="--model: add to ICP's template the midpoints to each canonical point's N nearest neighbours "
                   "(equipose.runtime.template; default 0 = off; chair-partial ships with 4); the calibration runs "
                   "with them")
    p.add_argument("--visibility", type=float, default=None,
                   help="with --model, partial-view models: rank the refined hypotheses by the view-aware residual "
                   "with this hidden-point-removal exponent (equipose.runtime.visibility; e.g. 1; default off)")
    p.add_argument("--views", type=int, default=None,
                   help="partial mode: rendered views per training instance of the cache to use (default: the "
                        "checkpoint's training setting, else 10)")
    p.add_argument("--category", help="category (default: the checkpoint's)")
    p.add_argument("--mode", choices=["complete", "partial"], help="default: the checkpoint's")
    p.add_argument("--num", type=int, default=1024, help="category-frame training inputs used (default 1024)")
    p.add_argument("--out", help="write the calibrated checkpoint here instead")
    p.add_argument("--data-root", dest="data_root")
    p.add_argument("--cache-dir", dest="cache_dir")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--rotated", action="store_true",
                   help="present the category-frame inputs in seeded random rotations (undone on the predictions) "
                        "instead of the identity pose only")


def _run_model(args) -> int:
    from equipose.train.data.datasets import make_dataset
    from equipose.train.data.modelnet import default_data_root
    from equipose.runtime.estimator import PoseEstimator
    from equipose.export.onnx_export import update_metadata

    from equipose.train.evaluation.calibration import calibrate_onnx_refined
    est = PoseEstimator(args.model, threads=1, refine=0)
    category = args.category or est.category
    mode = args.mode or ("partial" if est.partial else "complete")
    if args.visibility is not None and not est.partial:
        raise ConfigError(f"--visibility applies to partial-view models; {args.model} is a complete-shape model")
    root = args.data_root or default_data_root()
    ds = make_dataset(root, category, mode, "train", est.num_points, train=True, cache_dir=args.cache_dir,
                      render_opts={"views": args.views or 10})
    rng = np.random.default_rng(args.seed)
    idx = rng.choice(len(ds), size=min(args.num, len(ds)), replace=False)
    canon = np.stack([ds.sample(int(i), np.random.default_rng([args.seed, int(i)]))["canonical"] for i in idx])
    cal = calibrate_onnx_refined(args.model, canon, k=args.refine, iters=args.refine_iters,
                                 unsigned_axis=(category == "can"), seed=args.seed, copies=args.copies,
                                 visibility=args.visibility, polish=args.polish, densify=args.densify)
    cal["inputs"] = f"{len(idx)} category-frame {category}/{mode} training samples"
    update_metadata(args.model, refine_calibration=cal)
    print(f"refined calibration (k={args.refine}, {args.refine_iters} ICP iterations, {args.copies} copies, "
          f"visibility {args.visibility}, polish {args.polish}, densify {args.densify}) from {cal['n']} inputs: "
          f"rotation inliers {cal['inlier_fraction']:.2f}, translation inliers {cal['translation_inlier_fraction']:.2f} "
          f"→ {args.model} (metadata refine_calibration)")
    return 0


def run(args) -> int:
    from equipose.train.fitting.checkpoint import model_from_checkpoint, save_checkpoint
    from equipose.train.data.datasets import make_dataset
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.evaluation.inference import calibrate_model
    if args.model:
        return _run_model(args)
    model, ckpt = model_from_checkpoint(args.checkpoint)
    category = args.category or ckpt["category"]
    mode = args.mode or ("partial" if ckpt["partial"] else "complete")
    cfg = ckpt.get("training", {}).get("config", {})
    # the training run's folders where they exist here (a checkpoint trained on another machine names its own)
    local = {k: cfg.get(k) for k in ("data_root", "cache_dir") if cfg.get(k) and pathlib.Path(cfg[k]).is_dir()}
    root = args.data_root or local.get("data_root") or default_data_root()
    ds = make_dataset(root, category, mode, "train", model.num_points, train=True, limit=cfg.get("train_limit"),
                      cache_dir=args.cache_dir or local.get("cache_dir"),
                      render_opts={"views": args.views or cfg.get("views", 10)})
    rng = np.random.default_rng(args.seed)
    idx = rng.choice(len(ds), size=min(args.num, len(ds)), replace=False)
    canon = np.stack([ds.sample(int(i), np.random.default_rng([args.seed, int(i)]))["canonical"] for i in idx])
    rots = None
    if args.rotated:
        from equipose.core.geometry import random_rotations
        rots = random_rotations(len(canon), seed=args.seed)
    cal = calibrate_model(model, canon, symmetry=ckpt["symmetry"], unsigned_axis=(category == "can"), seed=args.seed,
                          rotations=rots)
    cal["inputs"] = (f"{len(idx)} category-frame {category}/{mode} training samples"
                     + (" in seeded random rotations" if args.rotated else ""))
    ckpt["calibration"] = cal
    out = args.out or args.checkpoint
    save_checkpoint(out, model, category=ckpt["category"], scale=ckpt["scale"], symmetry=ckpt["symmetry"],
                    step=ckpt["step"], calibration=cal, training=ckpt.get("training"), metrics=ckpt.get("metrics"),
                    extra={"optimizer": ckpt.get("optimizer")})
    R = np.asarray(cal["rotation"])
    print(f"calibration from {cal['n']} inputs: rotation inliers {cal['inlier_fraction']:.2f}, translation inliers "
          f"{cal['translation_inlier_fraction']:.2f}, δR angle {np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))):.1f}° "
          f"→ {out}")
    return 0
