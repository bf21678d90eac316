"""Depth frame sources (live OAK camera, .mcap replay, PNG folders, PCD files) and the common ``Frame`` type.

A source is one module here that decorates its class with ``@register_source`` (see ``equipose.sources.base``).

Everything here imports lazily: depthai and pypcd4 load only when a source that needs them is used.
"""
from __future__ import annotations

from equipose.sources.base import Frame, FrameSource, open_source, register_source, registered_sources

__all__ = ["Frame", "FrameSource", "open_source", "register_source", "registered_sources", "FolderSource", "FolderWriter",
           "PcdSource", "McapReplay",
           "McapWriter", "OakCamera"]

_LAZY = {
    "FolderSource": ".folder", "FolderWriter": ".folder", "PcdSource": ".pcd", "McapReplay": ".mcap",
    "McapWriter": ".mcap", "OakCamera": ".oak",
}


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name], __name__), name)
    raise AttributeError(f"module 'equipose.sources' has no attribute {name!r}")
