"""``equipose export``: a checkpoint (or random weights of a preset) → one self-describing ONNX file [+ int8 copy].

Convention:
    ``-o X.onnx`` writes the fp32 model; ``--int8`` also writes ``X.int8.onnx`` next to it. Prints one summary line
    per file (path, size, node count) to stdout; errors go to stderr with exit status 2.
"""
from __future__ import annotations

import argparse
import pathlib

from equipose.core.errors import ConfigError
from equipose.core.presets import list_presets

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", "-c", type=pathlib.Path, help="training checkpoint (.pt) to export")
    src.add_argument("--preset", help=f"preset name for --random-init: one of {', '.join(list_presets())}")
    parser.add_argument("--random-init", action="store_true",
                        help="export random weights of --preset (tests, benchmarks); metadata says random_init")
    parser.add_argument("-o", "--output", type=pathlib.Path, required=True, help="output .onnx file")
    parser.add_argument("--int8", action="store_true", help="also write an int8-quantized copy X.int8.onnx")
    parser.add_argument("--mode", choices=("partial", "complete"), default="partial",
                        help="model variant for --random-init (default: partial)")
    parser.add_argument("--category", default=None,
                        help="category name (--random-init: default unknown; --checkpoint: overrides the checkpoint's)")
    parser.add_argument("--scale", type=float, default=None,
                        help="metres per model unit (--random-init: default 2.0; --checkpoint: overrides the "
                             "checkpoint's, e.g. to deploy a model trained on unit-normalised shapes at a metric size)")
    parser.add_argument("--seed", type=int, default=0, help="random seed for --random-init (default: 0)")
    parser.add_argument("--opset", type=int, default=None, help="ONNX opset (default: the exporter's, 20)")
    parser.add_argument("--no-verify", action="store_true", help="skip the onnxruntime-vs-torch parity self check")
    parser.add_argument("--format", type=int, choices=(1, 2, 3, 4), default=None, dest="format_version",
                        help="model file format: 4 (default for quotient presets: the runtime computes each layer's "
                             "kernel weights, the first layer's summed per kernel class, and the hypothesis "
                             "scores), 3 (the same, no class sums), 2 (default for the others: the runtime "
                             "computes the kNN inputs and the scores) or 1 (all inside the graph, one input; "
                             "docs/architecture.md)")


def _summary(path: pathlib.Path) -> str:
    import onnx

    from equipose.export.onnx_export import op_type_counts

    counts = op_type_counts(onnx.load(str(path), load_external_data=False))
    top = ", ".join(f"{k} {v}" for k, v in list(counts.items())[:6])
    return f"{path}  {path.stat().st_size / 1e6:.2f} MB  {sum(counts.values())} nodes ({top}, ...)"


def run(args) -> int:
    from equipose.export.onnx_export import DEFAULT_OPSET, export_checkpoint, export_random_model
    from equipose.models.int8 import quantize_int8

    opts = {"opset": args.opset or DEFAULT_OPSET, "verify": not args.no_verify, "format_version": args.format_version}
    if args.checkpoint is not None:
        if args.random_init:
            raise ConfigError("--random-init goes with --preset, not with --checkpoint")
        out = export_checkpoint(args.checkpoint, args.output, category=args.category, scale=args.scale, **opts)
    else:
        if not args.random_init:
            raise ConfigError("--preset needs --random-init (to export trained weights pass --checkpoint)")
        out = export_random_model(args.preset, args.output, partial=args.mode == "partial",
                                  category=args.category or "unknown", scale=2.0 if args.scale is None else args.scale,
                                  seed=args.seed, **opts)
    print(_summary(out))
    if args.int8:
        print(_summary(quantize_int8(out)))
    return 0
