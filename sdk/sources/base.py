"""The common frame type, the source interface and the source registry (``register_source``, ``open_source``).

Convention:
    A ``Frame`` carries ``depth`` [H, W] in ``depth_unit`` ("mm": uint16 millimetres, 0 = invalid — every bundled
    source delivers this), ``K`` [3, 3] intrinsics of the depth frame (``image_size`` (W, H) when K belongs to another
    resolution, else None), optional ``rgb`` [H, W, 3] BGR uint8 registered to the depth, ``index`` (0-based) and
    ``timestamp`` (seconds, None if unknown).
    A source is an iterable of frames with ``close()`` and context-manager support. Unreadable sources raise
    ``SourceError``; a bad individual frame is yielded as a ``FrameError`` record by sources that can tell (the stream
    carries on) — see ``equipose.runtime.tracking``.
"""
from __future__ import annotations

import importlib
import pathlib
import pkgutil
from dataclasses import dataclass

import numpy as np

from equipose.core.errors import SourceError

__all__ = ["Frame", "FrameSource", "SourceEntry", "register_source", "registered_sources", "open_source"]


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


@dataclass(frozen=True)
class SourceEntry:
    """One registered source: ``cls`` opens a path (``cls(path, **kw)``) or, for an alias, takes keywords only."""
    name: str
    cls: type
    suffixes: tuple = ()
    aliases: tuple = ()
    folder: object = None          # callable(pathlib.Path) -> bool: whether a directory is this source's


_REGISTRY: dict = {}               # name → SourceEntry, in registration order


def register_source(name: str, *, suffixes=(), aliases=(), folder=None):
    """Class decorator: make ``open_source`` open files ending in ``suffixes`` (e.g. ``(".mcap",)``), the spec
    strings in ``aliases`` (e.g. ``("oak",)``, opened with keywords only) and directories for which ``folder(path)``
    is true. Re-registering a name replaces its entry."""
    def deco(cls):
        _REGISTRY[name] = SourceEntry(name, cls, tuple(s.lower() for s in suffixes), tuple(a.lower() for a in aliases),
                                      folder)
        return cls
    return deco


def _load_bundled() -> None:
    """Import every module of ``equipose.sources`` once (each registers its sources; heavy deps stay lazy)."""
    if _load_bundled.done:
        return
    _load_bundled.done = True
    package = importlib.import_module("equipose.sources")
    for info in pkgutil.iter_modules(package.__path__):
        if not info.name.startswith("_") and info.name != "base":
            importlib.import_module(f"equipose.sources.{info.name}")


_load_bundled.done = False


def registered_sources() -> list:
    """The registered ``SourceEntry`` records (bundled ones included), in registration order."""
    _load_bundled()
    return list(_REGISTRY.values())


def open_source(spec, **kwargs) -> FrameSource:
    """A frame source for ``spec``: a registered alias (``"oak"`` → ``OakCamera``), a file with a registered suffix
    (``.mcap`` → ``McapReplay``, ``.pcd`` → ``PcdSource``) or a directory a source claims (``intrinsics.json`` →
    ``FolderSource``, ``*.pcd`` → ``PcdSource``). Raises ``SourceError`` otherwise."""
    if isinstance(spec, FrameSource):
        return spec
    entries = registered_sources()
    s = str(spec)
    for e in entries:
        if s.lower() in e.aliases:
            return e.cls(**kwargs)
    p = pathlib.Path(s)
    if not p.exists():
        raise SourceError(f"source {s!r} does not exist; pass a PNG folder (with intrinsics.json), a .mcap or .pcd "
                          "file, or 'oak' for a live OAK camera")
    if p.is_file():
        for e in entries:
            if p.suffix.lower() in e.suffixes:
                return e.cls(p, **kwargs)
    if p.is_dir():
        for e in entries:
            if e.folder is not None and e.folder(p):
                return e.cls(p, **kwargs)
        raise SourceError(f"folder {s!r} has neither intrinsics.json (PNG depth folder) nor .pcd files")
    raise SourceError(f"cannot open {s!r}: unknown source type (expected a folder, .mcap, .pcd or 'oak')")
