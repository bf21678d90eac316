"""torch → ONNX export of an ``EquiPoseNet``: one self-contained file with the equipose metadata contract.

Convention:
    Input ``points`` float32 [batch, N, 3], model units (metres / ``scale``), FPS-ordered; N fixed per model
    (metadata ``num_points``), batch dynamic. Outputs (DESIGN.md "The ONNX contract"):
    ``canonical_shape`` [batch, M, 3], ``hypothesis_rotations`` [batch, 60, 3, 3] (act on column vectors),
    ``hypothesis_translations`` [batch, 60, 3] (model units, input frame), ``hypothesis_scores`` [batch, 60]
    (lower is better). Hypothesis j is the group rotation ``icosahedral.ANCHORS[j]`` (metadata ``anchors``).
    The graph uses the default ONNX domain only; the group tables are constant int64 ``Gather`` indices.

Uses the torch 2.13 ``torch.export``-based exporter (``dynamo=True``, needs onnxscript) with weights inlined.
"""
from __future__ import annotations

import contextlib
import io
import logging
import os
import pathlib
import sys
import warnings

import numpy as np

from equipose.core.errors import ConfigError, ModelFormatError
from equipose.core.metadata import encode_metadata

__all__ = ["DEFAULT_OPSET", "OUTPUT_NAMES", "INPUT_NAME", "export_model", "export_random_model", "export_checkpoint", "update_metadata",
           "calibration_arrays", "op_type_counts"]

DEFAULT_OPSET = 20
INPUT_NAME = "points"
OUTPUT_NAMES = ("canonical_shape", "hypothesis_rotations", "hypothesis_translations", "hypothesis_scores")
MAX_BATCH = 4096          # upper bound declared for the dynamic batch dimension
PARITY_ATOL = 1e-4        # export-time self check: ORT vs torch on the example batch


def _contract_module(model):
    """Wrap ``model`` so that forward returns the four contract outputs as a tuple (what the exporter traces)."""
    import torch

    class _Contract(torch.nn.Module):
        def __init__(self, net):
            super().__init__()
            self.net = net

        def forward(self, points):                       # points [B, N, 3]
            out = self.net(points)
            return tuple(out[k] for k in OUTPUT_NAMES)

    return _Contract(model).eval()


@contextlib.contextmanager
def _quiet_exporter():
    """Silence the exporter's progress prints (stdout), its torchvision registration log lines and warnings."""
    loggers = [logging.getLogger(n) for n in ("torch.onnx", "torch.onnx._internal.exporter._registration",
                                              "torch.export", "torch._export", "onnxscript")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    except BaseException:
        sys.stderr.write(buf.getvalue())                  # the exporter's own report helps when it fails
        raise
    finally:
        for lg, lv in zip(loggers, levels):
            lg.setLevel(lv)


def calibration_arrays(calibration) -> tuple:
    """Checkpoint calibration ``{"rotation": 3×3, "translation": 3}`` (or None = identity) → (R [3, 3], t [3])."""
    if calibration is None:
        return np.eye(3), np.zeros(3)
    if not isinstance(calibration, dict) or "rotation" not in calibration or "translation" not in calibration:
        raise ConfigError("calibration must be None or a dict with 'rotation' (3×3) and 'translation' (3), got "
                          f"{type(calibration).__name__}")
    R = np.asarray(calibration["rotation"], dtype=np.float64)
    t = np.asarray(calibration["translation"], dtype=np.float64)
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise ConfigError(f"calibration rotation must be finite 3×3 and translation finite 3, got {R.shape}, {t.shape}")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
        raise ConfigError("calibration rotation is not a proper rotation matrix (RᵀR ≠ I or det < 0)")
    return R, t


def op_type_counts(model_proto) -> dict:
    """``{op_type: count}`` over the top-level graph nodes, most frequent first."""
    counts: dict = {}
    for node in model_proto.graph.node:
        key = node.op_type if node.domain in ("", "ai.onnx") else f"{node.domain}::{node.op_type}"
        counts[key] = counts.get(key, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def _drop_initializer_value_info(proto):
    """Remove ``value_info`` entries of initializers (the exporter writes them; they go stale when a tool such as
    onnxruntime's quantizer transposes a weight in place, and then shape inference fails)."""
    inits = {t.name for t in proto.graph.initializer}
    keep = [vi for vi in proto.graph.value_info if vi.name not in inits]
    del proto.graph.value_info[:]
    proto.graph.value_info.extend(keep)


def _write_atomic(model_proto, path: pathlib.Path):
    import onnx

    tmp = path.with_name(path.name + ".tmp")
    onnx.save_model(model_proto, str(tmp))              # weights inline: one file (< 2 GB protobuf limit)
    os.replace(tmp, path)


def export_model(model, path, *, category: str, scale: float, symmetry: str = "none", calibration=None, handle=None,
                 shape_prior: str | None = None,
                 random_init: bool = False, training: dict | None = None, metrics: dict | None = None,
                 opset: int = DEFAULT_OPSET, verify: bool = True) -> pathlib.Path:
    """Export an ``EquiPoseNet`` to a single self-describing ONNX file and return its path.

    Args:
        model: ``equipose.train.EquiPoseNet`` (exported in eval mode; its training flag is restored).
        path: output ``.onnx`` file (parent folders are created; written atomically).
        category, scale (metres per model unit), symmetry, calibration ({"rotation", "translation"} or None),
        handle ([3] handle direction in the category frame, or None), shape_prior ("cylinder" or None), random_init,
            training, metrics: written to ``metadata_props`` via ``equipose.core.metadata.encode_metadata``.
        opset: ONNX opset of the default domain.
        verify: run the file once in onnxruntime on the export example and compare with torch (max abs ≤ 1e-4).
    Raises:
        ConfigError / MetadataError for bad arguments; RuntimeError if the exported graph disagrees with torch.
    """
    import onnx
    import torch

    from equipose.train.network.model import EquiPoseNet

    if not isinstance(model, EquiPoseNet):
        raise ConfigError(f"export_model needs an equipose.train.EquiPoseNet, got {type(model).__name__}")
    if not isinstance(category, str) or not category.strip():
        raise ConfigError("category must be a non-empty string (e.g. 'airplane', 'mug')")
    try:
        scale = float(scale)
    except (TypeError, ValueError):
        raise ConfigError(f"scale must be a number (metres per model unit), got {scale!r}") from None
    if not (np.isfinite(scale) and scale > 0):
        raise ConfigError(f"scale must be a positive finite number of metres per model unit, got {scale}")
    cal_R, cal_t = calibration_arrays(calibration)
    cfg = model.config
    meta = encode_metadata(category=category, preset=cfg.name, model_config=cfg.to_dict(), num_points=cfg.num_points,
                           num_canonical_points=cfg.num_canonical_points, scale=scale, partial=model.partial,
                           symmetry=symmetry, calibration_rotation=cal_R, calibration_translation=cal_t,
                           random_init=random_init, training=training, metrics=metrics, handle=handle,
                           shape_prior=shape_prior)
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    was_training = model.training
    wrapper = _contract_module(model)                                     # sets eval mode on the net
    gen = torch.Generator().manual_seed(1234)
    example = torch.randn(2, cfg.num_points, 3, generator=gen) * 0.2       # [2, N, 3]; batch 2 keeps the dim symbolic
    batch = torch.export.Dim("batch", min=1, max=MAX_BATCH)
    try:
        with _quiet_exporter(), torch.no_grad():
            program = torch.onnx.export(wrapper, (example,), None, dynamo=True, external_data=False,
                                        input_names=[INPUT_NAME], output_names=list(OUTPUT_NAMES),
                                        dynamic_shapes=({0: batch},), opset_version=int(opset), optimize=True)
        proto = program.model_proto
    finally:
        model.train(was_training)
    proto.doc_string = (f"equipose {cfg.name} model for category {category!r}: points [batch, {cfg.num_points}, 3] "
                        "(model units) -> canonical shape + 60 pose hypotheses with chamfer scores")
    _drop_initializer_value_info(proto)
    del proto.metadata_props[:]
    for k, v in meta.items():
        proto.metadata_props.add(key=k, value=v)
    onnx.checker.check_model(proto, full_check=True)
    _write_atomic(proto, path)
    if verify:
        _verify_parity(wrapper, path, example)
    return path


def _verify_parity(wrapper, path: pathlib.Path, example):
    """Run the written file in onnxruntime on ``example`` [B, N, 3] and compare all outputs with torch."""
    import onnxruntime as ort
    import torch

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    got = sess.run(list(OUTPUT_NAMES), {INPUT_NAME: example.numpy()})
    with torch.no_grad():
        ref = [t.numpy() for t in wrapper(example)]
    errs = {n: float(np.abs(a - b).max()) for n, a, b in zip(OUTPUT_NAMES, got, ref)}
    bad = {n: e for n, e in errs.items() if not e <= PARITY_ATOL}
    if bad:
        raise RuntimeError(f"exported {path} disagrees with torch beyond {PARITY_ATOL}: {bad}")


def export_random_model(preset, path, partial: bool = True, category: str = "unknown", scale: float = 2.0,
                        seed: int = 0, **kwargs) -> pathlib.Path:
    """Export a randomly initialised model of ``preset`` (tests, benchmarks, demo placeholder); ``random_init`` set."""
    import torch

    from equipose.train.network.model import EquiPoseNet

    torch.manual_seed(int(seed))
    try:
        model = EquiPoseNet(preset, partial=partial)
    except ValueError as e:                                                # unknown preset name
        raise ConfigError(str(e)) from None
    training = {"random_init": True, "seed": int(seed), "mode": "partial" if partial else "complete"}
    return export_model(model.eval(), path, category=category, scale=scale, random_init=True,
                        training=kwargs.pop("training", training), **kwargs)


MAX_LIST_IN_METADATA = 32


def _summary_of(training: dict) -> dict:
    """The checkpoint's training dict without per-step logs (lists longer than 32 entries, e.g. step times),
    which would bloat every model file; their names are listed under ``"omitted"``."""
    keep, omitted = {}, []
    for k, v in training.items():
        if isinstance(v, (list, tuple)) and len(v) > MAX_LIST_IN_METADATA:
            omitted.append(k)
        else:
            keep[k] = v
    if omitted:
        keep["omitted"] = omitted
    return keep


def export_checkpoint(checkpoint, path, *, category: str | None = None, scale: float | None = None,
                      **kwargs) -> pathlib.Path:
    """Export a training checkpoint (``equipose.train.checkpoint`` format) with its category, scale, symmetry,
    calibration, training summary and metrics. ``category`` / ``scale`` (metres per model unit) override the
    checkpoint's (the training summary then records the original as ``trained_category`` / ``trained_scale``)."""
    from equipose.train.fitting.checkpoint import model_from_checkpoint

    checkpoint = pathlib.Path(checkpoint)
    if not checkpoint.is_file():
        raise ConfigError(f"checkpoint {checkpoint} does not exist (train one with 'equipose train', or export "
                          "random weights with 'equipose export --preset P --random-init')")
    try:
        model, ckpt = model_from_checkpoint(checkpoint)
    except Exception as e:                                                 # pickle, key, shape mismatches
        raise ModelFormatError(f"{checkpoint} is not a readable equipose checkpoint: {e}") from None
    training = _summary_of(ckpt.get("training") or {})
    training.setdefault("step", int(ckpt.get("step", 0)))
    training.setdefault("mode", "partial" if model.partial else "complete")
    if category is not None and category != ckpt.get("category"):
        training["trained_category"] = ckpt.get("category")
    if scale is not None and scale != ckpt.get("scale"):
        training["trained_scale"] = ckpt.get("scale")
    from equipose.train.data.tabletop import TABLETOP
    category = category or ckpt.get("category", "unknown")               # e.g. a cup network exported as "mug"
    spec = TABLETOP.get(category)
    kwargs.setdefault("handle", (1.0, 0.0, 0.0) if spec is not None and spec.handle else None)
    kwargs.setdefault("shape_prior", "cylinder" if category == "can" else None)
    return export_model(model, path, category=category,
                        scale=scale if scale is not None else ckpt.get("scale", 1.0),
                        symmetry=ckpt.get("symmetry", "none"), calibration=ckpt.get("calibration"),
                        random_init=False, training=training, metrics=ckpt.get("metrics") or {}, **kwargs)


def update_metadata(path, **values) -> pathlib.Path:
    """Rewrite metadata entries of an exported model in place (dicts are stored as JSON), e.g. ``metrics=`` after an
    evaluation of that very file. The result is re-validated with ``equipose.core.metadata.decode_metadata``."""
    import json
    import os

    import onnx

    from equipose.core.metadata import decode_metadata

    path = pathlib.Path(path)
    try:
        proto = onnx.load(str(path))
    except Exception as e:                                                 # protobuf decode errors, missing file
        raise ModelFormatError(f"{path} is not a readable ONNX model: {e}") from None
    meta = {p.key: p.value for p in proto.metadata_props}
    for k, v in values.items():
        meta[k] = json.dumps(v) if isinstance(v, (dict, list)) else str(v)
    decode_metadata(meta, source=str(path))
    del proto.metadata_props[:]
    for k, v in meta.items():
        proto.metadata_props.add(key=k, value=v)
    tmp = path.with_name(path.name + ".tmp")
    onnx.save_model(proto, str(tmp))
    os.replace(tmp, path)
    return path
