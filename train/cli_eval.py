"""``equipose eval``: the paper's table for one category and mode — ours (a checkpoint, or an exported ONNX model
through ``equipose.PoseEstimator``) and ICP-60 + template from the same command; optional JSON and percentile PNG.

Convention: rotation errors in degrees (symmetric categories: up-axis angle); translation errors divided by the
instance's bbox diagonal; 5°0.05 = rotation ≤ 5° and translation ≤ 0.05; flip = rotation error > 150°.
"""
from __future__ import annotations

from .evaluate import evaluate, format_table, plot_percentiles, write_json


def add_arguments(p) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", help="a trained (and calibrated) checkpoint")
    src.add_argument("--model", help="an exported .onnx model (evaluated through the SDK)")
    p.add_argument("--category", required=True)
    p.add_argument("--mode", choices=["complete", "partial"], required=True)
    p.add_argument("--json", help="write the table as JSON here")
    p.add_argument("--plot", help="write a PNG of error-percentile curves here")
    p.add_argument("--limit", type=int, help="first K test instances only")
    p.add_argument("--icp-templates", dest="icp_templates", type=int, default=3)
    p.add_argument("--icp-points", dest="icp_points", type=int, default=256, help="observed points used by ICP")
    p.add_argument("--icp-iters", dest="icp_iters", type=int, default=20)
    p.add_argument("--icp-samples", dest="icp_samples", type=int,
                   help="run ICP on an evenly spaced subset of this many test samples (its row then carries 'n')")
    p.add_argument("--data-root", dest="data_root")
    p.add_argument("--cache-dir", dest="cache_dir")
    p.add_argument("--threads", type=int, default=1, help="torch threads")


def run(args) -> int:
    import torch
    torch.set_num_threads(max(1, args.threads))
    res = evaluate(category=args.category, mode=args.mode, checkpoint=args.checkpoint, model_path=args.model,
                   data_root=args.data_root, limit=args.limit, icp_templates=args.icp_templates,
                   icp_points=args.icp_points, icp_iters=args.icp_iters, icp_samples=args.icp_samples, cache_dir=args.cache_dir)
    print(format_table(res))
    if args.json:
        write_json(res, args.json)
    if args.plot:
        plot_percentiles(res, args.plot)
    return 0
