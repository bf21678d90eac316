"""Lazy, quiet depthai import shared by the depthai-based sources (never triggers a device search)."""
from __future__ import annotations

import os

from equipose.core.errors import SourceError


def import_depthai():
    """``import depthai`` with ``DEPTHAI_LEVEL=error`` (its import banner goes to stdout otherwise)."""
    os.environ.setdefault("DEPTHAI_LEVEL", "error")
    try:
        import depthai as dai
    except ImportError:
        raise SourceError("this source needs depthai v3: pip install 'equipose[camera]' (or pip install depthai)") from None
    if not hasattr(dai.node, "ReplayMessage"):
        raise SourceError(f"depthai {getattr(dai, '__version__', '?')} is too old; equipose needs depthai ≥ 3.0")
    return dai
