"""Training-time augmentation of rendered partial views for distillation.

Convention: model units, camera frame; target poses map the canonical frame into the view, ``x = R y + t``.
"""
from __future__ import annotations

import numpy as np
import torch

from equipose.core.errors import ConfigError

__all__ = ["rotate_views"]


def rotate_views(points: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor,
                 rng: np.random.Generator) -> tuple:
    """Turn each view about its centroid by its own uniform random rotation Q, and its target pose with it.

    Convention: ``points`` [B, N, 3] model units (camera frame), target poses ``x = R y + t`` with ``rotations``
    [B, 3, 3] and ``translations`` [B, 3]. With centroid c: x' = Q (x − c) + c, R' = Q R, t' = Q (t − c) + c, so
    every posed target shape lands on the turned view exactly. Returns (points', rotations', translations').
    """
    if points.ndim != 3 or points.shape[-1] != 3 or rotations.shape != (len(points), 3, 3) \
            or translations.shape != (len(points), 3):
        raise ConfigError(f"rotate_views needs points [B, N, 3], rotations [B, 3, 3], translations [B, 3]; got "
                          f"{tuple(points.shape)}, {tuple(rotations.shape)}, {tuple(translations.shape)}")
    from scipy.spatial.transform import Rotation
    Q = torch.as_tensor(Rotation.random(len(points), random_state=rng).as_matrix(), dtype=points.dtype,
                        device=points.device)                                  # [B, 3, 3]
    c = points.mean(1, keepdim=True)                                           # [B, 1, 3] centroid
    p = torch.einsum("bij,bnj->bni", Q, points - c) + c                        # [B, N, 3]
    R = torch.einsum("bij,bjk->bik", Q, rotations)                             # [B, 3, 3]
    t = torch.einsum("bij,bj->bi", Q, translations - c[:, 0]) + c[:, 0]        # [B, 3]
    return p, R, t
