"""Recover a trainable checkpoint from an exported ONNX file (continue training a shipped model).

The exporter keeps most weights as initializers named after the state dict (``net.<key>``). Two things change on the
way: some ``Linear`` weights are stored transposed under generated names (``val_N``) as MatMul operands, and the
optimiser fuses each ``Linear → BatchNorm1d`` pair of the head MLPs into one ``Gemm`` (the named weight then holds the
fused product). Recovery:

* named initializers are copied; a missing ``Linear`` weight is the single unnamed initializer of its transposed
  shape that feeds a MatMul whose result is added to that layer's (named) bias;
* a bias that an InstanceNormalization cancels is not in the graph (``equipose.export.graph_rewrite``): the metadata
  entry ``dropped_biases`` names it and its layer's MatMul weight; it comes back as zeros (any value gives the same
  outputs);
* each fused BatchNorm gets running statistics measured on ``calib_points`` (the fused layer's own pre-activation
  mean / variance) and the affine pair that undoes them exactly (γ = √(var + ε), β = mean), so the network in eval
  mode is the exported function to float rounding and in training mode starts from the same batch statistics.

Convention:
    ``calib_points`` [B, N, 3] float32 in model units (a batch of training inputs); the result is the checkpoint dict
    of ``train/fitting/checkpoint.py`` (no optimiser state: a fresh Adam starts on ``--resume``).
"""
from __future__ import annotations

import json
import pathlib

import numpy as np
import torch

from equipose.errors import ConfigError
from equipose.core.presets import ModelConfig

from equipose.train.fitting.checkpoint import CHECKPOINT_FORMAT
from equipose.train.network.model import EquiPoseNet

__all__ = ["checkpoint_from_onnx"]

_PREFIX = "net."


def _initializers(proto) -> dict:
    from onnx import numpy_helper
    return {t.name: numpy_helper.to_array(t) for t in proto.graph.initializer}


def _transposed_weight(proto, inits: dict, bias_name: str, shape: tuple, dropped: dict) -> np.ndarray:
    """The [out, in] weight of the Linear whose MatMul output is added to ``bias_name`` (stored as [in, out]);
    for a bias the graph rewrite dropped (``dropped``: the ``dropped_biases`` metadata), the MatMul it names."""
    w = inits.get(dropped.get(bias_name, ""))
    if w is not None and tuple(w.shape) == (shape[1], shape[0]):
        return w.T.copy()
    producers = {o: n for n in proto.graph.node for o in n.output}
    for node in proto.graph.node:
        if node.op_type != "Add" or bias_name not in node.input:
            continue
        other = [i for i in node.input if i != bias_name][0]
        mm = producers.get(other)
        if mm is None or mm.op_type != "MatMul":
            continue
        for name in mm.input:
            w = inits.get(name)
            if w is not None and tuple(w.shape) == (shape[1], shape[0]):
                return w.T.copy()
    cands = [n for n, w in inits.items() if not n.startswith(_PREFIX) and tuple(w.shape) == (shape[1], shape[0])]
    if len(cands) == 1:
        return inits[cands[0]].T.copy()
    raise ConfigError(f"cannot locate the weight for {bias_name!r} ({len(cands)} candidates of its transposed shape)")


def _fused_batchnorms(model: torch.nn.Module) -> list:
    """(Linear, BatchNorm1d) pairs inside the head MLPs (``nn.Sequential(Linear, BatchNorm1d, ReLU)``)."""
    pairs = []
    for mod in model.modules():
        if isinstance(mod, torch.nn.Sequential) and len(mod) == 3 and isinstance(mod[0], torch.nn.Linear) \
                and isinstance(mod[1], torch.nn.BatchNorm1d):
            pairs.append((mod[0], mod[1]))
    return pairs


@torch.no_grad()
def checkpoint_from_onnx(path, calib_points: np.ndarray | None = None, *, seed: int = 0) -> dict:
    """Checkpoint dict for the network in ``path`` (an equipose ONNX file, fp32). Raises ``ConfigError``.

    ``calib_points`` [B, N, 3]: inputs for the BatchNorm statistics (default: 64 random Gaussian blobs, which keeps
    eval-mode outputs exact but gives training-mode statistics of a less typical batch).
    """
    import onnx
    path = pathlib.Path(path)
    if not path.is_file():
        raise ConfigError(f"ONNX file {path} does not exist")
    proto = onnx.load(str(path))
    meta = {p.key: p.value for p in proto.metadata_props}
    if "model_config" not in meta:
        raise ConfigError(f"{path} has no equipose metadata (model_config); export it with 'equipose export'")
    if meta.get("precision", "fp32") != "fp32":
        raise ConfigError(f"{path} is a {meta['precision']} file: recover weights from its fp32 sibling")
    cfg = ModelConfig.from_dict(json.loads(meta["model_config"]))
    partial = json.loads(meta.get("partial", "false"))
    model = EquiPoseNet(cfg, partial=partial).eval()
    inits = _initializers(proto)
    fused = _fused_batchnorms(model)
    fused_bn = {id(bn) for _, bn in fused}
    bn_names = {name for name, mod in model.named_modules() if id(mod) in fused_bn}
    state = model.state_dict()
    dropped = json.loads(meta.get("dropped_biases", "{}"))                # biases an InstanceNorm cancels
    for key, ref in state.items():
        owner = key.rsplit(".", 1)[0]
        if owner in bn_names:                                     # filled from measured statistics below
            continue
        if _PREFIX + key in inits:
            value = inits[_PREFIX + key]
        elif key.endswith(".weight") and ref.dim() == 2:
            value = _transposed_weight(proto, inits, _PREFIX + owner + ".bias", tuple(ref.shape), dropped)
        elif _PREFIX + key in dropped:                              # no effect on any output: any value will do
            value = np.zeros(tuple(ref.shape), np.float32)
        elif key.endswith("num_batches_tracked"):
            continue
        else:
            raise ConfigError(f"{path}: no initializer for {key!r}")
        if tuple(value.shape) != tuple(ref.shape):
            raise ConfigError(f"{path}: {key!r} has shape {value.shape}, the model expects {tuple(ref.shape)}")
        state[key] = torch.tensor(np.array(value), dtype=ref.dtype)
    model.load_state_dict(state)
    for _, bn in fused:                                           # identity in eval mode until measured
        bn.running_mean.zero_()
        bn.running_var.fill_(1.0 - bn.eps)
        bn.weight.fill_(1.0)
        bn.bias.zero_()
    if calib_points is None:
        rng = np.random.default_rng(seed)
        calib_points = (rng.standard_normal((64, cfg.num_points, 3)) * [0.3, 0.2, 0.1]).astype(np.float32)
    x = torch.as_tensor(np.asarray(calib_points, np.float32))
    if x.dim() != 3 or x.shape[-1] != 3:
        raise ConfigError(f"calib_points must be [B, N, 3], got {tuple(x.shape)}")
    stats = {}
    hooks = [lin.register_forward_hook(lambda m, i, o, bn=bn: stats.__setitem__(id(bn), o.reshape(-1, o.shape[-1])))
             for lin, bn in fused]
    model(x)
    for h in hooks:
        h.remove()
    for _, bn in fused:
        y = stats[id(bn)].double()                                # [rows, C] fused pre-activations
        mean, var = y.mean(0), y.var(0, unbiased=False).clamp_min(1e-6)
        bn.running_mean.copy_(mean.float())
        bn.running_var.copy_(var.float())
        bn.weight.copy_(torch.sqrt(var + bn.eps).float())
        bn.bias.copy_(mean.float())
    training = json.loads(meta.get("training", "{}") or "{}")
    calib = None
    if "calibration_rotation" in meta:
        calib = {"rotation": json.loads(meta["calibration_rotation"]),
                 "translation": json.loads(meta.get("calibration_translation", "[0, 0, 0]"))}
    return {"format": CHECKPOINT_FORMAT, "model_config": cfg.to_dict(), "partial": partial,
            "category": meta.get("category", "unknown"), "scale": float(meta.get("scale", 1.0)),
            "symmetry": meta.get("symmetry", "none"),
            "state_dict": {k: v.detach().clone() for k, v in model.state_dict().items()},
            "step": int(training.get("step") or (training.get("config") or {}).get("steps") or 0),
            "optimizer": None, "calibration": calib, "training": training,
            "metrics": json.loads(meta.get("metrics", "{}") or "{}"), "recovered_from": path.name}
