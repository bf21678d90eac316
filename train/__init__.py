"""equipose.train — the torch side: EPN-60 model, self-supervised training, calibration, evaluation.

Needs the ``train`` extra (``pip install equipose[train]``, torch==2.13.0).
"""
from .model import EquiPoseNet, chamfer_min_of_60_loss, hypothesis_scores, quaternion_to_matrix, OUTPUT_NAMES

__all__ = ["EquiPoseNet", "chamfer_min_of_60_loss", "hypothesis_scores", "quaternion_to_matrix", "OUTPUT_NAMES"]
