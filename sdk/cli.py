"""The ``equipose`` command line. Mirrors the Python API; each subcommand lives in its own module.

Every subcommand is one module of ``equipose.commands`` with ``add_arguments(parser)`` and ``run(args) -> int``. Only
the chosen subcommand's module is imported; torch-side commands import the train extra inside ``run``, so ``--help``
works without it and a missing extra gives a clear install hint.
"""
from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["main", "COMMANDS", "TRAIN_EXTRA"]

TRAIN_EXTRA = ("torch", "onnx", "onnxscript", "tqdm", "matplotlib")   # top-level modules of the train extra

# name → (module in equipose.commands, one-line help, needs the train extra)
COMMANDS = {
    "demo": ("equipose.commands.demo", "run the bundled sample through the bundled model; print poses, save overlays", False),
    "predict": ("equipose.commands.predict", "estimate poses on a depth source (folder, .mcap, .pcd, OAK camera)", False),
    "record": ("equipose.commands.record", "record frames from any source to .mcap or a PNG folder", False),
    "models": ("equipose.commands.models", "list the models shipped with the package", False),
    "bench": ("equipose.commands.bench", "CPU latency benchmark (onnxruntime fp32/int8, torch, ICP-60)", False),
    "model-info": ("equipose.commands.model_info", "parameters and multiply-accumulates of a preset, per layer", False),
    "train": ("equipose.commands.train", "self-supervised training (complete clouds or rendered partial depth)", True),
    "calibrate": ("equipose.commands.calibrate", "RANSAC frame calibration of a trained checkpoint", True),
    "eval": ("equipose.commands.eval", "paper-style evaluation (ours next to ICP-60)", True),
    "render": ("equipose.commands.render", "render and cache partial-depth training data", True),
    "export": ("equipose.commands.export", "export a checkpoint (or random weights) to a self-describing ONNX file", True),
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
    module = importlib.import_module(module_name)          # torch-side commands import their dependencies in run()
    parser = argparse.ArgumentParser(prog=f"equipose {name}", description=help_text)
    module.add_arguments(parser)
    args = parser.parse_args(argv[1:])
    from equipose.core.errors import EquiposeError
    try:
        return int(module.run(args) or 0)
    except EquiposeError as e:
        print(f"equipose {name}: error: {e}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as e:
        if needs_train and e.name and e.name.split(".")[0] in TRAIN_EXTRA:
            print(f"equipose {name}: needs the train extra ({e.name} is missing). "
                  f"Install it with: pip install 'equipose[train]' (torch==2.13.0)", file=sys.stderr)
            return 2
        raise

if __name__ == "__main__":
    raise SystemExit(main())
