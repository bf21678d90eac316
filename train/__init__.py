"""equipose.train — the torch side: EPN-60 model, self-supervised training, calibration, evaluation.

Subpackages, by concern:
    data        ModelNet / mesh reading, the depth renderer and its caches, tabletop and scene data, the datasets
    network     the EPN-60 model and its layers; widening; weights recovered from shipped ONNX files
    fitting     training config, losses, distillation, the training loop, checkpoints, the turn classifier
    evaluation  frame calibration, batched inference, the evaluation harness, the ICP-60 baseline
    lanes       long runs over ``train/state/`` (slices, lanes of slices, snapshots) and weight averaging
    release     ``python -m equipose.train.release MODEL``: ship a model from its recipe
``bench_backends`` (torch and ICP-60 benchmark backends) stays at the top: ``equipose.bench.backends`` names it.
``python -m equipose.train.{long_runs,averaging,turn_classifier,widen}`` still run under their old names.

Needs the ``train`` extra (``pip install equipose[train]``, torch==2.13.0). The model names below import torch
lazily, so torch-free helpers of this package (e.g. ``equipose.train.evaluation.icp``) load without it.
"""
_LAZY = {"EquiPoseNet": "network.model", "hypothesis_scores": "network.model",
         "quaternion_to_matrix": "network.model", "OUTPUT_NAMES": "network.model",
         "chamfer_min_of_60_loss": "fitting.losses"}

__all__ = list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(f"equipose.train.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'equipose.train' has no attribute {name!r}")
