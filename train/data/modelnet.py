"""Shape files of the training data: ModelNet40 1024-point clouds and procedural cylinders, and the data root.

Convention:
    Files: ``<root>/modelnet40_npy1024/<cat>/{train,test}/<cat>_NNNN.npy``, float32 [1024, 3], centred, max radius 1,
    in the category frame (up = +z; see shared/data/SOURCES.md). File units are treated as "metres" of the object, so
    a checkpoint's ``scale`` (``MODELNET_SCALE`` = 2.0) maps them to model units with max radius 0.5.
"""
from __future__ import annotations

import os
import pathlib

import numpy as np

from equipose.core.errors import ConfigError

__all__ = ["default_data_root", "modelnet_files", "load_modelnet", "load_complete", "MODELNET_SCALE",
           "SYMMETRIC_CATEGORIES", "category_symmetry", "TEST_ROTATIONS", "TEST_SEED"]

MODELNET_SCALE = 2.0               # file units per model unit: max radius 1 → 0.5
# ``mug``: the network learns the axis only; the SDK's handle stage (equipose.runtime.handle) finds the azimuth
SYMMETRIC_CATEGORIES = ("bottle", "bowl", "cup", "can", "cylinder", "mug")
TEST_ROTATIONS = 5                 # paper protocol: 5 random rotations per test instance
TEST_SEED = 2913


def default_data_root() -> pathlib.Path:
    """``$EQUIPOSE_DATA`` if set, else ``../shared/data`` beside the repository."""
    env = os.environ.get("EQUIPOSE_DATA")
    if env:
        return pathlib.Path(env)
    return pathlib.Path(__file__).resolve().parents[3] / "shared" / "data"     # beside the repository


def category_symmetry(category: str) -> str:
    """The network's symmetry: ``continuous:z`` for rotationally symmetric categories (and ``mug``, whose handle the SDK
    resolves from the points), else ``none``."""
    return "continuous:z" if category in SYMMETRIC_CATEGORIES else "none"


def modelnet_files(root, category: str, split: str) -> list:
    """Sorted ``.npy`` paths of one category and split (official ModelNet40 split)."""
    if split not in ("train", "test"):
        raise ConfigError(f"split must be 'train' or 'test', got {split!r}")
    d = pathlib.Path(root) / "modelnet40_npy1024" / category / split
    files = sorted(d.glob("*.npy"))
    if not files:
        raise ConfigError(f"no ModelNet40 clouds under {d}; set --data-root or $EQUIPOSE_DATA "
                          f"(expected <root>/modelnet40_npy1024/<category>/<split>/*.npy)")
    return files


def load_modelnet(root, category: str, split: str, limit: int | None = None) -> tuple:
    """(clouds [S, 1024, 3] float32 in file units, instance ids [S] str)."""
    files = modelnet_files(root, category, split)[:limit]
    return np.stack([np.load(f).astype(np.float32) for f in files]), [f.stem for f in files]


# Complete-shape categories built from another ModelNet category plus procedural closed cylinders (``shapes``):
# ``can`` = ModelNet bottles (nearly all taller than wide) + cylinders of every proportion, h/d 0.25–4.
PROCEDURAL_COMPLETE = {"can": {"modelnet": "bottle", "cylinders": {"train": 200, "test": 40}},
                       "cylinder": {"modelnet": None, "cylinders": {"train": 400, "test": 40}}}   # cylinders only


def load_complete(root, category: str, split: str, limit: int | None = None) -> tuple:
    """Complete clouds of a category: (clouds [S, 1024, 3] float32 at max radius 1, as the ModelNet files, ids [S]).

    A ModelNet40 category as is; ``can`` = the ModelNet bottles followed by seeded procedural cylinders (ids
    ``cylinder_K``); ``cylinder`` = procedural cylinders only (experiments). ``limit`` keeps the first K of each part.
    """
    spec = PROCEDURAL_COMPLETE.get(category)
    if spec is None:
        return load_modelnet(root, category, split, limit)
    from equipose.train.data.shapes import cylinder_proportions, cylinder_surface
    if spec["modelnet"]:
        clouds, ids = load_modelnet(root, spec["modelnet"], split, limit)
    else:
        clouds, ids = np.zeros((0, 1024, 3), np.float32), []
    n = spec["cylinders"][split] if limit is None else min(limit, spec["cylinders"][split])
    split_id = 0 if split == "train" else 1
    rng = np.random.default_rng([TEST_SEED, split_id, 5])
    cyl = []
    for k, (r, h) in enumerate(cylinder_proportions(n, seed=[TEST_SEED, split_id, 6])):
        p = cylinder_surface(r, h, clouds.shape[1], rng)
        cyl.append((p / np.linalg.norm(p, axis=1).max()).astype(np.float32))      # max radius 1, like the files
    return np.concatenate([clouds, np.stack(cyl)]) if cyl else clouds, list(ids) + [f"cylinder_{k}" for k in range(n)]
