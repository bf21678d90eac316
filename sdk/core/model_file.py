"""An ONNX model file's equipose metadata, read straight from its protobuf (no onnxruntime session, no inference).

Convention:
    An ONNX file is a serialized ``ModelProto``; its custom metadata is the repeated field 14 ``metadata_props`` of
    ``StringStringEntryProto`` (field 1 ``key``, field 2 ``value``, UTF-8) — the map onnxruntime exposes as
    ``custom_metadata_map`` and ``equipose.export`` writes. Only the top level is walked: the graph (field 7) is
    skipped by its length, so reading costs one file read whatever the model's size. Standard library only.
"""
from __future__ import annotations

import pathlib

from equipose.core.errors import ModelFormatError
from equipose.core.metadata import decode_metadata

__all__ = ["read_metadata_props", "read_metadata"]

_GRAPH, _METADATA_PROPS = 7, 14          # ModelProto field numbers
_KEY, _VALUE = 1, 2                      # StringStringEntryProto field numbers


def _varint(buf: memoryview, i: int) -> tuple:
    """(value, next offset) of the base-128 varint at ``buf[i]``."""
    out = shift = 0
    while True:
        if i >= len(buf) or shift > 63:
            raise ValueError("truncated or overlong varint")
        b = buf[i]
        out |= (b & 0x7F) << shift
        i, shift = i + 1, shift + 7
        if not b & 0x80:
            return out, i


def _fields(buf: memoryview):
    """Yield (field number, wire type, value) of one protobuf message; length-delimited values as memoryviews."""
    i = 0
    while i < len(buf):
        tag, i = _varint(buf, i)
        num, wire = tag >> 3, tag & 7
        if num == 0:
            raise ValueError("field number 0")
        if wire == 0:
            val, i = _varint(buf, i)
        elif wire == 1 or wire == 5:
            n = 8 if wire == 1 else 4
            if i + n > len(buf):
                raise ValueError("truncated fixed-width field")
            val, i = buf[i:i + n], i + n
        elif wire == 2:
            n, i = _varint(buf, i)
            if i + n > len(buf):
                raise ValueError(f"field {num} runs past the end of the data")
            val, i = buf[i:i + n], i + n
        else:
            raise ValueError(f"unsupported wire type {wire}")
        yield num, wire, val


def read_metadata_props(path) -> dict:
    """The ``{key: value}`` custom metadata map (both ``str``) of the ONNX file ``path``, without loading the graph.

    Raises ``ModelFormatError`` when the file cannot be read or is not an ONNX model (not a ``ModelProto`` with a
    graph).
    """
    path = pathlib.Path(path)
    hint = "pass an .onnx file written by 'equipose export'"
    try:
        data = memoryview(path.read_bytes())
    except OSError as e:
        raise ModelFormatError(f"{path.name} is not a loadable ONNX model ({type(e).__name__}: "
                               f"{e.strerror or e}); {hint}") from None
    props, has_graph = {}, False
    try:
        for num, wire, val in _fields(data):
            if num == _GRAPH and wire == 2:
                has_graph = True
            elif num == _METADATA_PROPS and wire == 2:
                entry = {n: bytes(v).decode("utf-8") for n, w, v in _fields(val) if w == 2 and n in (_KEY, _VALUE)}
                props[entry.get(_KEY, "")] = entry.get(_VALUE, "")
    except (ValueError, UnicodeDecodeError) as e:
        raise ModelFormatError(f"{path.name} is not a loadable ONNX model (malformed protobuf: {e}); {hint}") from None
    if not has_graph:
        raise ModelFormatError(f"{path.name} is not a loadable ONNX model (no graph); {hint}")
    return props


def read_metadata(path) -> dict:
    """The decoded equipose metadata of a model file (``equipose.core.metadata.decode_metadata``; no inference).

    Raises ``ModelFormatError`` (not an ONNX file), ``MetadataError`` / ``ModelVersionError`` (not a valid equipose
    model).
    """
    path = pathlib.Path(path)
    return decode_metadata(read_metadata_props(path), source=path.name)
