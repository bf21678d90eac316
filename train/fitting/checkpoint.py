"""Checkpoint format shared by training, calibration, evaluation and export.

A checkpoint is ``torch.save`` of a dict:
    format            1
    model_config      ``ModelConfig.to_dict()`` (re-built with ``ModelConfig.from_dict``)
    partial           bool
    category          str
    scale             float, metres per model unit
    symmetry          "none" | "continuous:z" | ...
    state_dict        model weights
    step              int, optimisation steps done
    optimizer         optimiser state (for --resume), optional
    calibration       {"rotation": 3×3 list, "translation": 3 list, ...} or None (identity)
    training          dict: data summary, steps, batch size, seconds/step, ...
    metrics           dict: test metrics (filled by eval), may be empty
"""
from __future__ import annotations

import os
import pathlib

import torch

from equipose.core.errors import ConfigError
from equipose.core.presets import ModelConfig

from equipose.train.network.model import EquiPoseNet

__all__ = ["save_checkpoint", "load_checkpoint", "model_from_checkpoint", "clean_state_dict", "optimizer_to",
           "CHECKPOINT_FORMAT"]

CHECKPOINT_FORMAT = 1
_CONSTANT_BUFFERS = ("kernel_t", "kernel_sq", "kernel_aug", "table", "anchors", "anchors_cat")


def save_checkpoint(path, model: EquiPoseNet, *, category: str, scale: float, symmetry: str = "none",
                    step: int = 0, optimizer=None, calibration: dict | None = None, training: dict | None = None,
                    metrics: dict | None = None, extra: dict | None = None) -> pathlib.Path:
    """Write atomically (temp file + rename), so an interrupted save never corrupts the previous checkpoint."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {
        "format": CHECKPOINT_FORMAT, "model_config": model.config.to_dict(), "partial": model.partial,
        "category": category, "scale": float(scale), "symmetry": symmetry,
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}, "step": int(step),
        "optimizer": _on_cpu(optimizer.state_dict()) if optimizer is not None else None,
        "calibration": calibration, "training": training or {}, "metrics": metrics or {},
    }
    if extra:
        state.update(extra)
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)
    return path


def _on_cpu(tree):
    """``tree`` (nested dicts / lists of tensors, e.g. an optimiser state) with every tensor on the CPU, so a
    checkpoint written on a GPU loads with a plain ``torch.load`` anywhere."""
    if torch.is_tensor(tree):
        return tree.detach().cpu()
    if isinstance(tree, dict):
        return {k: _on_cpu(v) for k, v in tree.items()}
    if isinstance(tree, (list, tuple)):
        return type(tree)(_on_cpu(v) for v in tree)
    return tree


def load_checkpoint(path) -> dict:
    """Load a checkpoint dict (CPU tensors). Raises ``ConfigError`` (a ``ValueError``) on a missing or foreign file."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise ConfigError(f"checkpoint {path} does not exist; train one with 'equipose train' (runs/<name>/latest.pt)")
    try:                                    # tensors, dicts and primitives only: a pickle cannot run code here
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # pickle.UnpicklingError for forbidden globals, RuntimeError/EOFError for damaged files
        raise ConfigError(f"{path} cannot be loaded as an equipose checkpoint ({type(e).__name__}: "
                          f"{str(e).splitlines()[0][:160]}); only tensors, dicts and plain values are accepted — "
                          "a file that needs more is not a checkpoint written by 'equipose train'") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise ConfigError(f"{path} is not an equipose checkpoint (format {CHECKPOINT_FORMAT})")
    return ckpt


def optimizer_to(opt, device) -> None:
    """Move a (resumed) optimiser's state tensors to ``device`` in place — Adam's moments are loaded where the
    checkpoint was read (the CPU) and must sit with the parameters; ``step`` counters stay where they are."""
    for st in opt.state.values():
        for k, v in st.items():
            if torch.is_tensor(v) and k != "step":
                st[k] = v.to(device)


def clean_state_dict(state: dict) -> dict:
    """Drop constant tables (non-persistent buffers now) that older checkpoints stored with the weights."""
    return {k: v for k, v in state.items() if k.rsplit(".", 1)[-1] not in _CONSTANT_BUFFERS}


def model_from_checkpoint(ckpt_or_path) -> tuple:
    """(model in eval mode, checkpoint dict)."""
    ckpt = load_checkpoint(ckpt_or_path) if not isinstance(ckpt_or_path, dict) else ckpt_or_path
    model = EquiPoseNet(ModelConfig.from_dict(ckpt["model_config"]), partial=ckpt["partial"])
    model.load_state_dict(clean_state_dict(ckpt["state_dict"]))
    return model.eval(), ckpt
