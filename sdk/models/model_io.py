"""Reading and writing model files (``onnx.ModelProto``), shared by the int8 builder, the exporter and the graph
rewrites.

Convention: one self-contained ``.onnx`` file per model (weights inline, under the 2 GB protobuf limit); a write goes
to a temporary file beside the target (a unique name, so that two processes writing the same file do not collide) and
is renamed over it, so a reader never sees half a file.
"""
from __future__ import annotations

import os
import pathlib
import tempfile

from equipose.core.errors import ModelFormatError

__all__ = ["read_model_file", "write_model_file"]


def read_model_file(path):
    """The ``onnx.ModelProto`` in ``path``. Raises ``ModelFormatError`` for a missing or unreadable file."""
    import onnx
    try:
        return onnx.load(str(path))
    except Exception as e:                                                 # protobuf decode errors, missing file
        raise ModelFormatError(f"{path} is not a readable ONNX model: {e}") from None


def write_model_file(proto, path) -> pathlib.Path:
    """Write ``proto`` to ``path`` atomically (temp file + rename); its folder is created. Returns the path."""
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(proto.SerializeToString())
        os.replace(tmp, path)
    except BaseException:
        pathlib.Path(tmp).unlink(missing_ok=True)
        raise
    return path
