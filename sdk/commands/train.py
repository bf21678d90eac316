"""``equipose train``: self-supervised training on complete ModelNet clouds or rendered partial depth.

Convention:
    One flag per ``TrainConfig`` field (``equipose.train.fitting.config``): ``batch_size`` → ``--batch-size``, type
    from the annotation (``bool`` → ``--flag`` / ``--no-flag``), help from the field's metadata; adding a field adds
    its flag. Options come from defaults < ``--config F`` (JSON, field names) < explicit flags.
    Multi-process / multi-GPU: ``torchrun --standalone --nproc_per_node K -m equipose.cli train ...``
    (gloo on CPU, nccl on CUDA; ``--batch-size`` is per process).
"""
from __future__ import annotations

import argparse
import pathlib
import types
import typing

from equipose.core.presets import list_presets

__all__ = ["add_arguments", "add_config_arguments", "config_flag", "run"]


def config_flag(name: str) -> str:
    """The flag of a ``TrainConfig`` field: ``batch_size`` → ``--batch-size``."""
    return "--" + name.replace("_", "-")


def _value_type(annotation):
    """``int | None`` → int; plain types as they are."""
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return annotation


def add_config_arguments(p, config_cls) -> None:
    """One flag per field of the dataclass ``config_cls``; every flag defaults to None (= not given)."""
    import dataclasses
    hints = typing.get_type_hints(config_cls)
    for f in dataclasses.fields(config_cls):
        kind = _value_type(hints[f.name])
        text = f.metadata.get("help", "").format(presets=", ".join(list_presets()))
        if f.default is not None and f.default is not False and f.default != "":     # those say it in words
            text += f" (default {f.default})"
        opts = {"dest": f.name, "default": None, "help": text}
        if kind is bool:
            opts["action"] = argparse.BooleanOptionalAction
        else:
            opts["type"] = kind
            if "choices" in f.metadata:
                opts["choices"] = f.metadata["choices"]
        p.add_argument(config_flag(f.name), **opts)


def add_arguments(p) -> None:
    from equipose.train.fitting.config import TrainConfig
    add_config_arguments(p, TrainConfig)
    p.add_argument("--config", help="JSON file of TrainConfig options")
    p.add_argument("--resume", action="store_true", help="continue from OUT/latest.pt (weights, optimiser, step); "
                   "options default to OUT/config.json when no --config is given (e.g. --out train/state/car-complete)")


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
