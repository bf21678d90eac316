"""torch → ONNX export of an ``EquiPoseNet``: one self-contained file with the equipose metadata contract.

Convention:
    Input ``points`` float32 [batch, N, 3], model units (metres / ``scale``), FPS-ordered; N fixed per model
    (metadata ``num_points``), batch dynamic. Outputs (DESIGN.md "The ONNX contract", format 2):
    ``canonical_shape`` [batch, M, 3], ``hypothesis_rotations`` [batch, 60, 3, 3] (act on column vectors),
    ``hypothesis_translations`` [batch, 60, 3] (model units, input frame). Hypothesis j is the group rotation
    ``icosahedral.ANCHORS[j]`` (metadata ``anchors``). The hypothesis scores are not in the graph: the runtime
    computes them (``equipose.core.scores``, 4–7× faster than onnxruntime's MatMuls); ``strip_graph_scores`` turns a
    format-1 file, whose graph still outputs them, into a format-2 one with the same network.
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

__all__ = ["DEFAULT_OPSET", "OUTPUT_NAMES", "INPUT_NAME", "export_model", "export_random_model", "export_checkpoint",
           "update_metadata", "strip_graph_scores", "calibration_arrays", "op_type_counts"]

DEFAULT_OPSET = 20
INPUT_NAME = "points"
OUTPUT_NAMES = ("canonical_shape", "hypothesis_rotations", "hypothesis_translations")     # the graph's outputs
SCORES = "hypothesis_scores"                                                               # computed by the runtime
MAX_BATCH = 4096          # upper bound declared for the dynamic batch dimension
PARITY_ATOL = 1e-4        # export-time self check: ORT vs torch on the example batch


def _contract_module(model, names=OUTPUT_NAMES):
    """Wrap ``model`` so that forward returns the outputs ``names`` as a tuple (what the exporter traces)."""
    import torch

    class _Contract(torch.nn.Module):
        def __init__(self, net):
            super().__init__()
            self.net = net

        def forward(self, points):                       # points [B, N, 3]
            out = self.net(points)
            return tuple(out[k] for k in names)

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
                 opset: int = DEFAULT_OPSET, verify: bool = True, scores_in_graph: bool = False) -> pathlib.Path:
    """Export an ``EquiPoseNet`` to a single self-describing ONNX file and return its path.

    Args:
        model: ``equipose.train.EquiPoseNet`` (exported in eval mode; its training flag is restored).
        path: output ``.onnx`` file (parent folders are created; written atomically).
        category, scale (metres per model unit), symmetry, calibration ({"rotation", "translation"} or None),
        handle ([3] handle direction in the category frame, or None), shape_prior ("cylinder" or None), random_init,
            training, metrics: written to ``metadata_props`` via ``equipose.core.metadata.encode_metadata``.
        opset: ONNX opset of the default domain.
        verify: run the file once in onnxruntime on the export example and compare with torch (max abs ≤ 1e-4).
        scores_in_graph: also output ``hypothesis_scores`` from the graph (format 1, for readers of the ONNX file
            that do not compute them; the SDK runs either).
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
    names = OUTPUT_NAMES + ((SCORES,) if scores_in_graph else ())
    if scores_in_graph:
        meta["equipose_format"] = "1"
    wrapper = _contract_module(model, names)                              # sets eval mode on the net
    gen = torch.Generator().manual_seed(1234)
    example = torch.randn(2, cfg.num_points, 3, generator=gen) * 0.2       # [2, N, 3]; batch 2 keeps the dim symbolic
    batch = torch.export.Dim("batch", min=1, max=MAX_BATCH)
    try:
        with _quiet_exporter(), torch.no_grad():
            program = torch.onnx.export(wrapper, (example,), None, dynamo=True, external_data=False,
                                        input_names=[INPUT_NAME], output_names=list(names),
                                        dynamic_shapes=({0: batch},), opset_version=int(opset), optimize=True)
        proto = program.model_proto
    finally:
        model.train(was_training)
    proto.doc_string = (f"equipose {cfg.name} model for category {category!r}: points [batch, {cfg.num_points}, 3] "
                        "(model units) -> canonical shape + 60 pose hypotheses")
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
    """Run the written file in onnxruntime on ``example`` [B, N, 3] and compare all outputs with torch, the hypothesis
    scores as the runtime computes them (``equipose.runtime.session.with_scores``) with the network's own."""
    import onnxruntime as ort
    import torch

    from equipose.runtime.session import with_scores

    net = wrapper.net
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [o.name for o in sess.get_outputs()]
    got = with_scores(dict(zip(names, sess.run(names, {INPUT_NAME: example.numpy()}))),
                      example.numpy(), partial=net.partial, score_points=net.config.score_points)
    with torch.no_grad():
        ref = {k: v.numpy() for k, v in net(example).items()}
    errs = {n: float(np.abs(got[n] - ref[n]).max()) for n in OUTPUT_NAMES + (SCORES,)}
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


def strip_graph_scores(path, out=None) -> pathlib.Path:
    """A format-1 model file (its graph outputs ``hypothesis_scores``) → format 2: the same graph without the score
    nodes, every metadata entry kept, ``equipose_format`` set to 2. Written to ``out`` (default: in place); a
    format-2 file is copied unchanged. Works on fp32 and int8 files alike (the score nodes hold no weights)."""
    import onnx
    from onnx.utils import Extractor

    from equipose.core.metadata import FORMAT_VERSION

    path = pathlib.Path(path)
    out = path if out is None else pathlib.Path(out)
    try:
        proto = onnx.load(str(path))
    except Exception as e:                                                 # protobuf decode errors, missing file
        raise ModelFormatError(f"{path} is not a readable ONNX model: {e}") from None
    outputs = [o.name for o in proto.graph.output]
    if not set(OUTPUT_NAMES) <= set(outputs):
        raise ModelFormatError(f"{path}: outputs {outputs} lack {OUTPUT_NAMES}; not an equipose model")
    if SCORES in outputs:
        meta = {p.key: p.value for p in proto.metadata_props}
        sub = Extractor(proto).extract_model([INPUT_NAME], list(OUTPUT_NAMES))   # the nodes the three outputs need
        for field in ("ir_version", "producer_name", "producer_version", "doc_string"):
            setattr(sub, field, getattr(proto, field))
        del sub.opset_import[:]
        sub.opset_import.extend(proto.opset_import)
        meta["equipose_format"] = str(FORMAT_VERSION)
        for k, v in meta.items():
            sub.metadata_props.add(key=k, value=v)
        onnx.checker.check_model(sub, full_check=True)
        proto = sub
    out.parent.mkdir(parents=True, exist_ok=True)
    _write_atomic(proto, out)
    return out


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
