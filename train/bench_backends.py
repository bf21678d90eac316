"""Torch-side benchmark backends (torch eager, ICP-60 baseline), registered with ``equipose.bench.backends``.

Convention: both keep the SDK's crop and FPS ordering and replace only ``est.runner`` (model points [B, N, 3] model
units → the four output arrays). torch: eager ``EquiPoseNet`` with ``--checkpoint`` weights, else the export seed of
a random-init model (identical weights), else random weights of the same architecture (timing only; flagged); its
parity with the ONNX file is the max |Δ| of rotations and scores. icp60: 60 icosahedral starts, 30 iterations,
against the model's own canonical shape as template, best residual selected.
"""
from __future__ import annotations

import numpy as np

from equipose.core.presets import ModelConfig
from equipose.preprocess import prepare_points
from equipose.bench.backends import register_backend

__all__ = ["torch_forward", "setup_torch", "setup_icp60"]


def _first_input(est, frame, box) -> np.ndarray:
    """[1, N, 3] model points of the benchmark frame's object."""
    c0 = est.crop(frame.depth, frame.K, box=box, depth_unit=frame.depth_unit, image_size=frame.image_size)
    return prepare_points(c0.points, est.num_points, est.scale).model_points[None]


def torch_forward(est, checkpoint: str | None):
    """A callable model_points [B, N, 3] → outputs dict (numpy) with torch eager, plus a note on the weights."""
    import torch

    from equipose.train.fitting.checkpoint import model_from_checkpoint
    from equipose.train.network.model import EquiPoseNet

    training = est.metadata.get("training") or {}
    if checkpoint:
        model, _ = model_from_checkpoint(checkpoint)
        note = "checkpoint weights"
    else:
        seed = training.get("seed") if est.random_init else None
        torch.manual_seed(int(seed or 0))
        model = EquiPoseNet(ModelConfig.from_dict(est.metadata["model_config"]), partial=est.metadata["partial"])
        note = "same weights (export seed)" if seed is not None else "same architecture, random weights (timing only)"
    model.eval()

    def fwd(x):
        with torch.no_grad():
            out = model(torch.from_numpy(np.ascontiguousarray(x, np.float32)))
        return {k: v.numpy() for k, v in out.items()}

    return fwd, note


def setup_torch(est, frame, box, *, threads: int, checkpoint: str | None = None) -> tuple:
    """Run ``est`` on torch eager; returns (note, parity max |Δ| against the ONNX file)."""
    import torch
    torch.set_num_threads(threads)
    forward, note = torch_forward(est, checkpoint)
    x0 = _first_input(est, frame, box)                                          # [1, N, 3]
    a, b = forward(x0), est.run_model(x0)
    parity = float(max(np.abs(a[k] - b[k]).max() for k in ("hypothesis_rotations", "hypothesis_scores")))
    est.runner = forward
    return note, parity


def setup_icp60(est, frame, box, *, threads: int, checkpoint: str | None = None) -> tuple:
    """Run ``est`` as ICP-60 against its own canonical shape (the template); returns ("", None)."""
    from equipose.train.evaluation.icp import icp60_outputs
    template = est.run_model(_first_input(est, frame, box))["canonical_shape"][0].astype(np.float64)  # [M, 3]
    partial = bool(est.metadata["partial"])
    est.runner = lambda x: icp60_outputs(x, template, iters=30, bidirectional=not partial)
    return "", None


register_backend("torch", setup_torch)
register_backend("icp60", setup_icp60)
