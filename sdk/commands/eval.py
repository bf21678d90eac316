"""``equipose eval``: the paper's table for one category and mode — ours (a checkpoint, or an exported ONNX model
through ``equipose.PoseEstimator``) and ICP-60 + template from the same command; optional JSON and percentile PNG.

Convention: rotation errors in degrees (symmetric categories: up-axis angle); translation errors divided by the
instance's bbox diagonal; 5°0.05 = rotation ≤ 5° and translation ≤ 0.05; flip = rotation error > 150°.

With ``--dataset ycbv:DIR | bop:DIR | graspnet:DIR`` it evaluates exported models on annotated real RGB-D frames
instead (``equipose.eval.datasets``: rotation / axis errors in degrees, centre errors in mm, 5°5cm and 10°5cm, per
object and prompt); then ``--category`` / ``--mode`` do not apply and ``--model`` may list one model per category.
"""
from __future__ import annotations

from equipose.commands import stage_options
from equipose.core.errors import ConfigError


def add_arguments(p) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", help="a trained (and calibrated) checkpoint")
    src.add_argument("--model", help="an exported .onnx model (evaluated through the SDK)")
    p.add_argument("--category", help="the test set's category (required without --dataset)")
    p.add_argument("--mode", choices=["complete", "partial"], help="complete | partial (required without --dataset)")
    p.add_argument("--dataset", help="evaluate on annotated real frames: ycbv:DIR, bop:DIR or graspnet:DIR (with "
                                     "--model NAME[,NAME...]: one exported model per category)")
    p.add_argument("--object", action="append", dest="objects",
                   help="with --dataset: only this object (mapping name or id; repeatable)")
    p.add_argument("--prompt", default="both", choices=["box", "mask", "both", "auto", "all"],
                   help="with --dataset: the region given to the SDK: the visible mask, its bounding box, both "
                        "(default), the SDK's own tabletop segmentation (auto), or all three")
    p.add_argument("--overlays", help="with --dataset: a folder for one JPEG per frame and prompt (≤ 640 px wide)")
    p.add_argument("--mapping", help="with --dataset: an object-mapping TOML (default: the dataset's shipped one, "
                                     "equipose/eval/datasets/{ycbv,graspnet}.toml)")
    p.add_argument("--json", help="write the table as JSON here")
    p.add_argument("--plot", help="write a PNG of error-percentile curves here")
    p.add_argument("--limit", type=int, help="first K test instances only")
    p.add_argument("--icp-templates", dest="icp_templates", type=int, default=3)
    p.add_argument("--icp-points", dest="icp_points", type=int, default=256, help="observed points used by ICP")
    p.add_argument("--icp-iters", dest="icp_iters", type=int, default=20)
    p.add_argument("--icp-samples", dest="icp_samples", type=int,
                   help="run ICP on an evenly spaced subset of this many test samples (its row then carries 'n')")
    p.add_argument("--exclude", default="", help="comma-separated test instances to leave out (e.g. 0629,0637)")
    p.add_argument("--exclude-suspects", dest="exclude_suspects", action="store_true",
                   help="leave out the category's suspect test instances (shared/data/SOURCES.md)")
    p.add_argument("--data-root", dest="data_root")
    p.add_argument("--cache-dir", dest="cache_dir")
    p.add_argument("--threads", type=int, default=1, help="torch threads")
    p.add_argument("--refine", type=int, default=None,
                   help="with --model: ICP re-scoring of the K best hypotheses in the SDK (PoseEstimator(refine=K); "
                        "default: the file's own setting, 'auto')")
    p.add_argument("--copies", type=int, default=None,
                   help="with --model: rotated input copies per object (PoseEstimator(copies=K); default: the file's "
                        "own setting, 'auto')")
    p.add_argument("--profile", default="default",
                   help="with --model: the SDK profile (fast, default, accurate; PoseEstimator(profile=...))")
    p.add_argument("--stages", default=None,
                   help='with --model: stage options as JSON, e.g. \'{"rescore": {"iters": 10}, "turn": false}\'')
    p.add_argument("--up", choices=["gt", "plane", "none"], default=None,
                   help="with --model: give the SDK each view's true up axis as the up prior (the setting of a user "
                        "with a level IMU or a table plane; PoseEstimator.predict(..., up=...)); ICP-60 does not use it. "
                        "With --dataset also 'plane' (the frame's support plane) or 'none' (default)")
    p.add_argument("--store-metrics", dest="store_metrics", action="store_true",
                   help="with --model: write this table into the model file's 'metrics' metadata (what "
                        "'equipose models' lists)")


def _run_dataset(args) -> int:
    """``--dataset``: the real-data evaluation of ``equipose.eval.datasets`` (torch-free)."""
    from equipose.eval.datasets.run import evaluate_dataset, format_table, write_json
    if args.checkpoint:
        raise ConfigError("--dataset evaluates exported models: give --model NAME[,NAME...] (an .onnx or shipped "
                          "name per category), not --checkpoint")
    if args.category or args.mode:
        raise ConfigError("--category / --mode select the synthetic test set; with --dataset the mapping picks each "
                          "object's category from --model: drop them")
    if args.store_metrics or args.plot or args.stages or args.exclude or args.exclude_suspects:
        raise ConfigError("--store-metrics / --plot / --stages / --exclude apply to the synthetic test set, not to "
                          "--dataset")
    res = evaluate_dataset(args.dataset, args.model, objects=args.objects, prompt=args.prompt, limit=args.limit,
                           profile=args.profile, up=args.up, mapping=args.mapping, overlays=args.overlays)
    print(format_table(res))
    if args.json:
        write_json(res, args.json)
    return 0


def run(args) -> int:
    if getattr(args, "dataset", None):
        return _run_dataset(args)
    if not args.category or not args.mode:
        raise ConfigError("equipose eval needs --category and --mode (the synthetic test set), or --dataset "
                          "KIND:DIR for annotated real frames")
    if args.up in ("plane", "none"):
        raise ConfigError(f"--up {args.up} is for --dataset; the synthetic test set takes --up gt or nothing")
    if any(getattr(args, k, None) for k in ("objects", "overlays", "mapping")) or args.prompt != "both":
        raise ConfigError("--object / --prompt / --overlays / --mapping apply with --dataset only")
    from equipose.train.evaluation.evaluate import (evaluate, format_table, metrics_for_metadata, plot_percentiles,
                                                    write_json)
    import torch
    torch.set_num_threads(max(1, args.threads))
    from equipose.train.evaluation.evaluate import SUSPECT_TEST_INSTANCES
    exclude = [e for e in args.exclude.split(",") if e]
    if args.exclude_suspects:
        exclude += list(SUSPECT_TEST_INSTANCES.get(args.category, ()))
    if args.store_metrics and (args.up or args.stages or args.profile != "default"):
        raise ConfigError("--store-metrics stores the default profile's metrics; drop --up / --stages / --profile")
    if args.store_metrics and args.up:
        raise ConfigError("--store-metrics stores the plain setting's metrics; drop --up")
    if exclude and args.store_metrics:
        raise ConfigError("--store-metrics stores the full test set's metrics; drop --exclude / --exclude-suspects")
    res = evaluate(category=args.category, mode=args.mode, checkpoint=args.checkpoint, model_path=args.model,
                   data_root=args.data_root, limit=args.limit, icp_templates=args.icp_templates,
                   icp_points=args.icp_points, icp_iters=args.icp_iters, icp_samples=args.icp_samples, cache_dir=args.cache_dir,
                   refine=args.refine, copies=args.copies, exclude=exclude, up=args.up, profile=args.profile,
                   stages=stage_options(args.stages))
    if args.store_metrics and not args.model:
        raise ConfigError("--store-metrics needs --model (the metrics describe that file)")
    print(format_table(res))
    if args.store_metrics:
        from equipose.export.onnx_export import update_metadata
        update_metadata(args.model, metrics=metrics_for_metadata(res))
        print(f"stored the metrics in {args.model}")
    if args.json:
        write_json(res, args.json)
    if args.plot:
        plot_percentiles(res, args.plot)
    return 0
