"""On-disk layout of rendered partial-view caches: keyed file names and the atomic ``.npz`` writer.

Convention: a cache holds concatenated points [ΣP, 3] (model units) with offsets, poses (rotations [V, 3, 3], metric
translations [V, 3]), bbox diagonals, instance ids, ``scale`` (metres per model unit) and the settings key.
"""
from __future__ import annotations

import hashlib
import json
import pathlib

import numpy as np

__all__ = ["PIPELINE_VERSION", "default_cache_dir", "keyed_cache_path", "write_partial_cache"]


def default_cache_dir() -> pathlib.Path:
    return pathlib.Path(__file__).resolve().parents[2] / "data_cache"            # <repository>/data_cache


# Version of the render → crop pipeline whose output a cache holds; part of every cache key. Bump it whenever the
# renderer or ``equipose.preprocess`` changes the points it produces. 2: older caches came from an older
# crop (adaptive plane RANSAC, window crop) and differ from a fresh render by a few points per view.
PIPELINE_VERSION = 2


def keyed_cache_path(cache_dir, stem: str, settings: dict) -> tuple:
    """(settings JSON key, ``<cache_dir>/<stem>_<sha1(key)[:10]>.npz``); creates the folder. Every setting and the
    ``PIPELINE_VERSION`` are in the key, so a changed setting or pipeline names a new cache."""
    key = json.dumps({**settings, "pipeline": PIPELINE_VERSION}, sort_keys=True, default=str)
    cache_dir = pathlib.Path(cache_dir) if cache_dir else default_cache_dir()
    cache_dir.mkdir(parents=True, exist_ok=True)
    return key, cache_dir / f"{stem}_{hashlib.sha1(key.encode()).hexdigest()[:10]}.npz"


def write_partial_cache(path, pts: list, Rs: list, ts: list, diags: list, inst: list, *, scale: float, category: str,
                        key: str, seconds: float, **extra) -> pathlib.Path:
    """Write rendered views atomically in the ``RenderedPartial`` layout: concatenated points [ΣP, 3] + offsets, poses
    (metres), bbox diagonals, instance ids, ``scale`` (metres per model unit), category, settings key, frames/s."""
    path = pathlib.Path(path)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in pts])]).astype(np.int64)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, points=np.concatenate(pts), offsets=offsets, rotations=np.stack(Rs), translations=np.stack(ts),
             diags=np.array(diags), instances=np.array(inst), scale=np.float64(scale), category=np.str_(category),
             settings=np.str_(key), frames_per_second=np.float64(len(pts) / max(seconds, 1e-9)), **extra)
    tmp.replace(path)
    return path
