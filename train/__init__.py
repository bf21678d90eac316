"""equipose.train — the torch side: EPN-60 model, self-supervised training, calibration, evaluation.

Needs the ``train`` extra (``pip install equipose[train]``, torch==2.13.0). The model names below import torch
lazily, so torch-free helpers of this package (e.g. ``equipose.train.icp``, ``equipose.train.metrics``) load without it.
"""
_LAZY = ("EquiPoseNet", "chamfer_min_of_60_loss", "hypothesis_scores", "quaternion_to_matrix", "OUTPUT_NAMES")

__all__ = list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        from . import model
        return getattr(model, name)
    raise AttributeError(f"module 'equipose.train' has no attribute {name!r}")
