"""equipose — category-level 6D object pose from a depth camera, on a CPU.

The SDK core needs only numpy, onnxruntime, opencv and scipy (no torch). Heavy parts import lazily.
"""
from __future__ import annotations

__version__ = "0.56.0"

from equipose import errors  # noqa: F401  (cheap, always available)

_LAZY = {
    "PoseEstimator": ("equipose.runtime.estimator", "PoseEstimator"),
    "PoseResult": ("equipose.runtime.result", "PoseResult"),
    "load_model_points": ("equipose.core.model_points", "load_model_points"),
}

__all__ = ["__version__", "errors"] + sorted(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib
        mod, attr = _LAZY[name]
        return getattr(importlib.import_module(mod), attr)
    raise AttributeError(f"module 'equipose' has no attribute {name!r}")
