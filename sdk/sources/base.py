"""The common frame type and source interface, plus ``open_source`` (path/name → the right source).

Convention:
    A ``Frame`` carries ``depth`` [H, W] in ``depth_unit`` ("mm": uint16 millimetres, 0 = invalid — every bundled
    source delivers this), ``K`` [3, 3] intrinsics of the depth frame (``image_size`` (W, H) when K belongs to another
    resolution, else None), optional ``rgb`` [H, W, 3] BGR uint8 registered to the depth, ``index`` (0-based) and
    ``timestamp`` (seconds, None if unknown).
    A source is an iterable of frames with ``close()`` and context-manager support. Unreadable sources raise
    ``SourceError``; a bad individual frame is yielded as a ``FrameError`` record by sources that can tell (the stream
    carries on) — see ``equipose.tracking``.
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass

import numpy as np

from ..errors import SourceError

__all__ = ["Frame", "FrameSource", "open_source"]


@dataclass
class Frame:
    """One depth frame with its intrinsics (and optionally colour)."""
    depth: np.ndarray
    K: np.ndarray
    depth_unit: object = "mm"
    rgb: np.ndarray | None = None
    index: int = 0
    timestamp: float | None = None
    image_size: tuple | None = None
    name: str = ""

    @property
    def shape(self) -> tuple:
        return tuple(np.shape(self.depth)[:2])


class FrameSource:
    """Base class: iterate for frames; ``close()`` releases resources; usable as a context manager."""

    def __iter__(self):
        raise NotImplementedError

    def close(self):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __len__(self):  # sources that know their length override this
        raise TypeError(f"{type(self).__name__} has no known length")


def open_source(spec, **kwargs) -> FrameSource:
    """``"oak"`` → ``OakCamera``; a ``.mcap`` file → ``McapReplay``; a ``.pcd`` file (or a folder of them) →
    ``PcdSource``; a folder with ``intrinsics.json`` → ``FolderSource``. Raises ``SourceError`` otherwise."""
    if isinstance(spec, FrameSource):
        return spec
    s = str(spec)
    if s.lower() in ("oak", "oak:", "camera"):
        from .oak import OakCamera
        return OakCamera(**kwargs)
    p = pathlib.Path(s)
    if not p.exists():
        raise SourceError(f"source {s!r} does not exist; pass a PNG folder (with intrinsics.json), a .mcap or .pcd "
                          "file, or 'oak' for a live OAK camera")
    if p.is_file() and p.suffix.lower() == ".mcap":
        from .mcap import McapReplay
        return McapReplay(p, **kwargs)
    if p.is_file() and p.suffix.lower() == ".pcd":
        from .pcd import PcdSource
        return PcdSource(p, **kwargs)
    if p.is_dir():
        if (p / "intrinsics.json").is_file():
            from .folder import FolderSource
            return FolderSource(p, **kwargs)
        if sorted(p.glob("*.pcd")):
            from .pcd import PcdSource
            return PcdSource(p, **kwargs)
        raise SourceError(f"folder {s!r} has neither intrinsics.json (PNG depth folder) nor .pcd files")
    raise SourceError(f"cannot open {s!r}: unknown source type (expected a folder, .mcap, .pcd or 'oak')")
