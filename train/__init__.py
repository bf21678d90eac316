"""equipose.train — the torch side: EPN-60 model, self-supervised training, calibration, evaluation.

Needs the ``train`` extra (``pip install equipose[train]``, torch==2.13.0). The model names below import torch
lazily, so torch-free helpers of this package (e.g. ``equipose.train.icp``) load without it.
"""
_LAZY = {"EquiPoseNet": "model", "hypothesis_scores": "model", "quaternion_to_matrix": "model",
         "OUTPUT_NAMES": "model", "chamfer_min_of_60_loss": "losses"}

__all__ = list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(f"equipose.train.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'equipose.train' has no attribute {name!r}")
