"""The int8 copy of a model file: built from its fp32 file (onnxruntime dynamic quantization), on first use.

Convention:
    ``X.onnx`` (fp32) → ``X.int8.onnx`` in the same folder, or in the user cache when that folder is read-only
    (``$EQUIPOSE_CACHE/models/<first 16 hex of the fp32 file's SHA-256>/``, ``$EQUIPOSE_CACHE`` default
    ``~/.cache/equipose``). Input and output are the fp32 contract graph; only the feature MatMul/Gemm weights
    become int8, per output channel (activations are quantized per call, no calibration data); the coordinate
    MatMuls (inner size ≤ 8) stay fp32.

Metadata: the int8 file carries the fp32 file's entries, with ``precision = int8``, ``int8_source`` = the SHA-256 of
the fp32 file it was built from, and the entries that belong to the int8 network alone (its own metrics, its own
re-scoring calibration) taken from the fp32 file's ``int8_overrides`` (a JSON object of metadata strings).
``update_metadata`` on an int8 file records the values there, so a rebuilt copy keeps them.

onnxruntime's dynamic quantization is deterministic: the copy built from a shipped fp32 file gives the same outputs,
bit for bit, as the int8 file measured at release. A copy whose ``int8_source`` no longer matches its fp32 file
(the fp32 file was re-exported or its metadata changed) is rebuilt when the model is resolved.

Static QDQ quantization with ModelNet calibration clouds was measured and rejected (docs/training.md, "Export").
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import pathlib
import tempfile
import time

from equipose.core.errors import ConfigError, ModelFormatError
from equipose.models.model_io import write_model_file

__all__ = ["INT8_SUFFIX", "OVERRIDES_KEY", "SOURCE_KEY", "int8_path_for", "fp32_path_for", "quantize_int8",
           "ensure_int8", "is_derived_int8", "cache_dir"]

INT8_SUFFIX = ".int8.onnx"
OVERRIDES_KEY = "int8_overrides"     # fp32 metadata: {key: metadata string} that the int8 copy carries instead
SOURCE_KEY = "int8_source"           # int8 metadata: SHA-256 (hex) of the fp32 file it was built from
GEOMETRY_MAX_INNER = 8               # MatMuls with a constant B of inner size ≤ this (xyz · kernel frames) stay fp32

_log = logging.getLogger("equipose")


def int8_path_for(path) -> pathlib.Path:
    """``model.onnx`` → ``model.int8.onnx`` (same folder)."""
    path = pathlib.Path(path)
    stem = path.name[:-5] if path.name.endswith(".onnx") else path.name
    return path.with_name(stem + INT8_SUFFIX)


def fp32_path_for(path) -> pathlib.Path | None:
    """``model.int8.onnx`` → ``model.onnx`` (same folder); None for a name without the int8 suffix."""
    path = pathlib.Path(path)
    if not path.name.endswith(INT8_SUFFIX):
        return None
    return path.with_name(path.name[:-len(INT8_SUFFIX)] + ".onnx")


def cache_dir() -> pathlib.Path:
    """Where int8 copies of models in read-only folders are built: ``$EQUIPOSE_CACHE/models`` (default
    ``~/.cache/equipose/models``)."""
    root = os.environ.get("EQUIPOSE_CACHE") or pathlib.Path.home() / ".cache" / "equipose"
    return pathlib.Path(root) / "models"


def _sha256(path: pathlib.Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _geometry_matmuls(model) -> list:
    """Names of MatMul/Gemm nodes whose constant B has a tiny inner dimension (3: coordinates times kernel points or
    anchor frames). Quantizing them saves nothing and moves the kernel geometry by up to 1/255 of its range."""
    inits = {t.name: tuple(t.dims) for t in model.graph.initializer}
    names = []
    for node in model.graph.node:
        if node.op_type not in ("MatMul", "Gemm") or len(node.input) < 2 or node.input[1] not in inits:
            continue
        dims = inits[node.input[1]]
        trans_b = any(a.name == "transB" and a.i for a in node.attribute)
        inner = dims[-1] if trans_b else (dims[-2] if len(dims) >= 2 else dims[0])
        if inner <= GEOMETRY_MAX_INNER:
            names.append(node.name)
    return names


def _int8_metadata(meta: dict, source_sha: str, where: str) -> dict:
    """The int8 copy's metadata from its fp32 file's ``meta``: overrides applied, precision and source set."""
    meta = dict(meta)
    try:
        overrides = json.loads(meta.pop(OVERRIDES_KEY, "") or "{}")
    except json.JSONDecodeError as e:
        raise ModelFormatError(f"{where}: metadata {OVERRIDES_KEY} is not JSON ({e}); rewrite it with "
                               "update_metadata on the int8 file") from None
    if not isinstance(overrides, dict) or not all(isinstance(v, str) for v in overrides.values()):
        raise ModelFormatError(f"{where}: metadata {OVERRIDES_KEY} must map keys to metadata strings")
    meta.update(overrides)
    meta["precision"] = "int8"
    meta[SOURCE_KEY] = source_sha
    return meta


def quantize_int8(fp32_path, out_path=None, *, per_channel: bool = True,
                  keep_geometry_fp32: bool = True) -> pathlib.Path:
    """Write the dynamically int8-quantized copy of ``fp32_path`` (MatMul/Gemm weights) and return its path
    (default ``int8_path_for(fp32_path)``; written atomically). Raises ``ConfigError`` / ``ModelFormatError``.

    ``per_channel`` quantizes weights per output channel; ``keep_geometry_fp32`` leaves the coordinate MatMuls
    (inner size 3) in fp32.
    """
    try:
        import onnx
        from onnxruntime.quantization import QuantType, quantize_dynamic
    except ImportError as e:                                               # pragma: no cover - base dependencies
        raise ConfigError(f"building an int8 model needs the onnx package ({e}); pip install onnx") from None
    fp32_path = pathlib.Path(fp32_path)
    if not fp32_path.is_file():
        raise ConfigError(f"ONNX model {fp32_path} does not exist; export it first with 'equipose export'")
    out_path = int8_path_for(fp32_path) if out_path is None else pathlib.Path(out_path)
    raw_bytes = fp32_path.read_bytes()
    try:
        src = onnx.load_from_string(raw_bytes)
    except Exception as e:                                                 # protobuf decode errors
        raise ModelFormatError(f"{fp32_path} is not a readable ONNX model: {e}") from None
    meta = _int8_metadata({p.key: p.value for p in src.metadata_props}, hashlib.sha256(raw_bytes).hexdigest(),
                          str(fp32_path))
    del src.graph.value_info[:]                  # re-inferred by the quantizer; stale entries break it
    with tempfile.TemporaryDirectory(prefix="equipose-q-") as tmp:
        raw = pathlib.Path(tmp) / "q.onnx"
        root = logging.getLogger()
        level = root.level
        root.setLevel(logging.ERROR)             # the quantizer logs a "consider pre-processing" warning on root
        try:
            quantize_dynamic(src, str(raw), op_types_to_quantize=["MatMul", "Gemm"], per_channel=per_channel,
                             weight_type=QuantType.QInt8,
                             nodes_to_exclude=_geometry_matmuls(src) if keep_geometry_fp32 else [])
        finally:
            root.setLevel(level)
        q = onnx.load(str(raw))
    del q.metadata_props[:]
    for k, v in meta.items():
        q.metadata_props.add(key=k, value=v)
    q.doc_string = src.doc_string + " (int8 dynamic-quantized weights)"
    write_model_file(q, out_path)
    return out_path


def _source_of(path: pathlib.Path) -> str | None:
    """The ``int8_source`` entry of an int8 file (None when absent or unreadable)."""
    from equipose.core.model_file import read_metadata_props
    try:
        return read_metadata_props(path).get(SOURCE_KEY)
    except (OSError, ValueError):
        return None


def is_derived_int8(path) -> bool:
    """Whether ``path`` is an int8 copy built from the fp32 file beside it (``int8_source`` set, that file there)."""
    path = pathlib.Path(path)
    fp32 = fp32_path_for(path)
    return fp32 is not None and fp32.is_file() and path.is_file() and _source_of(path) is not None


def ensure_int8(fp32_path) -> pathlib.Path:
    """The path of an up-to-date int8 copy of ``fp32_path``: next to it (or in ``cache_dir()`` when its folder is
    read-only), built or rebuilt when missing or built from another version of the fp32 file."""
    fp32_path = pathlib.Path(fp32_path)
    if not fp32_path.is_file():
        raise ConfigError(f"ONNX model {fp32_path} does not exist; its int8 copy is built from it")
    beside = int8_path_for(fp32_path)
    writable = os.access(fp32_path.parent, os.W_OK)
    if beside.is_file() and _source_of(beside) is None:
        return beside                                                       # a stand-alone int8 file: left alone
    sha = _sha256(fp32_path)
    target = beside if writable else cache_dir() / sha[:16] / beside.name
    if target.is_file() and _source_of(target) == sha:
        return target
    t0 = time.perf_counter()
    out = quantize_int8(fp32_path, target)
    _log.info("built the int8 copy %s from %s in %.1f s (once)", out, fp32_path.name, time.perf_counter() - t0)
    return out
