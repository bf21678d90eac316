"""The ``equipose`` command line. Mirrors the Python API; each subcommand lives in its own module.

A subcommand module provides ``add_arguments(parser)`` and ``run(args) -> int``. Only the chosen subcommand's module
is imported, so runtime commands never import torch and torch-side commands fail with a clear install hint.
"""
from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["main", "COMMANDS"]

# name → (module, one-line help, needs the train extra)
COMMANDS = {
    "demo": ("equipose.commands.demo", "run the bundled sample through the bundled model; print poses, save overlays", False),
    "predict": ("equipose.commands.predict", "estimate poses on a depth source (folder, .mcap, .pcd, OAK camera)", False),
    "record": ("equipose.commands.record", "record frames from any source to .mcap or a PNG folder", False),
    "models": ("equipose.commands.models", "list the models shipped with the package", False),
    "bench": ("equipose.commands.bench", "CPU latency benchmark (onnxruntime fp32/int8, torch, ICP-60)", False),
    "model-info": ("equipose.commands.model_info", "parameters and multiply-accumulates of a preset, per layer", False),
    "train": ("equipose.train.cli_train", "self-supervised training (complete clouds or rendered partial depth)", True),
    "calibrate": ("equipose.train.cli_calibrate", "RANSAC frame calibration of a trained checkpoint", True),
    "eval": ("equipose.train.cli_eval", "paper-style evaluation (ours next to ICP-60)", True),
    "render": ("equipose.train.cli_render", "render and cache partial-depth training data", True),
    "export": ("equipose.export.cli", "export a checkpoint (or random weights) to a self-describing ONNX file", True),
}


def _top_parser() -> argparse.ArgumentParser:
    from equipose import __version__
    p = argparse.ArgumentParser(
        prog="equipose", formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Category-level 6D object pose from depth on a CPU.",
        epilog="commands:\n" + "\n".join(f"  {n:<11} {h}" + (" [train extra]" if t else "")
                                        for n, (_, h, t) in COMMANDS.items())
        + "\n\nRun 'equipose COMMAND --help' for a command's options.")
    p.add_argument("--version", action="version", version=f"equipose {__version__}")
    p.add_argument("command", choices=sorted(COMMANDS), metavar="COMMAND")
    return p


def main(argv=None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    top = _top_parser()
    if not argv or argv[0] in ("-h", "--help") or argv[0] == "--version":
        top.parse_args(argv or ["--help"])
        return 0
    name = argv[0]
    if name not in COMMANDS:
        top.print_usage(sys.stderr)
        print(f"equipose: unknown command {name!r}; choose from {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    module_name, help_text, needs_train = COMMANDS[name]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        if needs_train and e.name and e.name.split(".")[0] in ("torch", "onnx", "onnxscript", "tqdm", "matplotlib"):
            print(f"equipose {name}: needs the train extra ({e.name} is missing). "
                  f"Install it with: pip install 'equipose[train]' (torch==2.13.0)", file=sys.stderr)
            return 2
        raise
    parser = argparse.ArgumentParser(prog=f"equipose {name}", description=help_text)
    module.add_arguments(parser)
    args = parser.parse_args(argv[1:])
    from equipose.errors import EquiposeError
    try:
        return int(module.run(args) or 0)
    except EquiposeError as e:
        print(f"equipose {name}: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
