"""Models shipped with the package (ONNX files with equipose metadata).

``demo_mug_small.onnx``: the ``small`` preset with **random weights** (category "mug", partial-depth mode,
scale 0.25 m per model unit), a placeholder that exercises the whole pipeline until trained models are published.
Its poses are meaningless; its metadata says ``random_init = true``.
"""
from __future__ import annotations

import pathlib

__all__ = ["MODELS_DIR", "DEMO_MODEL", "demo_model_path", "list_models"]

MODELS_DIR = pathlib.Path(__file__).resolve().parent
DEMO_MODEL = "demo_mug_small.onnx"


def demo_model_path() -> pathlib.Path:
    """Path of the bundled demo model (random weights until trained models exist)."""
    return MODELS_DIR / DEMO_MODEL


def list_models() -> list:
    """Paths of all ``.onnx`` files shipped in this package, sorted."""
    return sorted(MODELS_DIR.glob("*.onnx"))
