"""Sample recordings shipped with the package (PNG-folder layout of ``equipose.sources.FolderSource``).

``table_mug``: one real 640×480 RGB-D frame of a mug on a table, from the Point Cloud Library data repository
(BSD-3-Clause; see ``table_mug/NOTICE``), with ``objects.json`` giving the mug's box.
"""
from __future__ import annotations

import json
import pathlib

__all__ = ["SAMPLES_DIR", "sample_path", "sample_objects", "sample_frame"]

SAMPLES_DIR = pathlib.Path(__file__).resolve().parent


def sample_path(name: str = "table_mug") -> pathlib.Path:
    """Folder of a bundled sample."""
    from equipose.core.errors import SourceError
    p = SAMPLES_DIR / name
    if not (p / "intrinsics.json").is_file():
        have = sorted(d.name for d in SAMPLES_DIR.iterdir() if (d / "intrinsics.json").is_file())
        raise SourceError(f"no bundled sample {name!r}; available: {', '.join(have) or 'none'}")
    return p


def sample_objects(name: str = "table_mug") -> list:
    """The ``objects`` list of a sample's ``objects.json`` (``[{"category", "box"}]``), or [] if absent."""
    f = sample_path(name) / "objects.json"
    return json.loads(f.read_text()).get("objects", []) if f.is_file() else []


def sample_frame(name: str = "table_mug"):
    """The first ``Frame`` of a bundled sample (depth uint16 mm [H, W], K [3, 3], rgb BGR or None)."""
    from equipose.sources.folder import FolderSource
    with FolderSource(sample_path(name)) as src:
        return next(iter(src))
