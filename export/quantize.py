"""int8 weight quantization of an exported equipose ONNX file (onnxruntime quantization tools).

Convention:
    Input and output are the fp32 contract graph (``points`` float32 [batch, N, 3] → the four float32 outputs); only
    the MatMul/Gemm weights become int8 (dynamic quantization: activations are quantized per call, no calibration
    data needed). The metadata props of the fp32 file are copied unchanged. ``X.onnx`` → ``X.int8.onnx``.
"""
from __future__ import annotations

import logging
import os
import pathlib
import tempfile

from equipose.errors import ConfigError, ModelFormatError

__all__ = ["int8_path_for", "quantize_int8"]


def int8_path_for(path) -> pathlib.Path:
    """``model.onnx`` → ``model.int8.onnx`` (same folder)."""
    path = pathlib.Path(path)
    stem = path.name[:-5] if path.name.endswith(".onnx") else path.name
    return path.with_name(stem + ".int8.onnx")


def quantize_int8(fp32_path, out_path=None, *, per_channel: bool = False) -> pathlib.Path:
    """Write a dynamically int8-quantized copy of ``fp32_path`` (MatMul/Gemm weights) and return its path.

    ``per_channel`` quantizes weights per output channel (slightly more accurate, slightly larger/slower).
    """
    import onnx
    from onnxruntime.quantization import QuantType, quantize_dynamic

    fp32_path = pathlib.Path(fp32_path)
    if not fp32_path.is_file():
        raise ConfigError(f"ONNX model {fp32_path} does not exist; export it first with 'equipose export'")
    out_path = int8_path_for(fp32_path) if out_path is None else pathlib.Path(out_path)
    try:
        src = onnx.load(str(fp32_path))
    except Exception as e:                                                 # protobuf decode errors
        raise ModelFormatError(f"{fp32_path} is not an ONNX model: {e}") from None
    meta = {p.key: p.value for p in src.metadata_props}
    del src.graph.value_info[:]                  # re-inferred by the quantizer; stale entries break it
    with tempfile.TemporaryDirectory(prefix="equipose-q-") as tmp:
        raw = pathlib.Path(tmp) / "q.onnx"
        root = logging.getLogger()
        level = root.level
        root.setLevel(logging.ERROR)             # the quantizer logs a "consider pre-processing" warning on root
        try:
            quantize_dynamic(src, str(raw), op_types_to_quantize=["MatMul", "Gemm"],
                             per_channel=per_channel, weight_type=QuantType.QInt8)
        finally:
            root.setLevel(level)
        q = onnx.load(str(raw))
    del q.metadata_props[:]
    for k, v in meta.items():
        q.metadata_props.add(key=k, value=v)
    q.doc_string = src.doc_string + " (int8 dynamic-quantized weights)"
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = out_path.with_name(out_path.name + ".tmp")
    onnx.save_model(q, str(tmp_out))
    os.replace(tmp_out, out_path)
    return out_path
