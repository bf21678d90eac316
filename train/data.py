"""Training and evaluation data: ModelNet40 1024-point complete clouds and cached rendered partial-depth clouds.

Convention:
    Files: ``<root>/modelnet40_npy1024/<cat>/{train,test}/<cat>_NNNN.npy``, float32 [1024, 3], centred, max radius 1,
    in the category frame (up = +z; see shared/data/SOURCES.md). We treat file units as "metres" of the object, so a
    checkpoint's ``scale`` (2.0 for ModelNet) maps them to model units with max radius 0.5.
    A sample is a dict of numpy arrays:
        points    [N, 3] float32  model units (metres / scale), FPS-ordered (nested prefixes), camera/world frame
        rotation  [3, 3]          ground truth R: x = R @ x_obj + t (reporting only; never reaches the loss)
        translation [3]           ground truth t, model units
        diag      float           bbox diagonal of the complete instance, model units (translation-error divisor)
        canonical [N, 3] float32  the same observed points mapped into the category frame, (x − t) @ R (calibration
                                  input, spec §6; the observed surface, un-rotated)
    Train: a fresh uniform SO(3) rotation per draw. Test: ``test_rotations`` seeded rotations per instance.
"""
from __future__ import annotations

import os
import pathlib

import numpy as np

from equipose.errors import ConfigError
from equipose.geometry import farthest_point_order, random_rotations

__all__ = ["default_data_root", "modelnet_files", "load_modelnet", "ModelNetComplete", "RenderedPartial",
           "MODELNET_SCALE", "SYMMETRIC_CATEGORIES", "category_symmetry", "make_dataset", "TEST_ROTATIONS",
           "TEST_SEED"]

MODELNET_SCALE = 2.0               # file units per model unit: max radius 1 → 0.5
SYMMETRIC_CATEGORIES = ("bottle", "bowl", "cup", "can", "cylinder")
TEST_ROTATIONS = 5                 # paper protocol: 5 random rotations per test instance
TEST_SEED = 2913


def default_data_root() -> pathlib.Path:
    """``$EQUIPOSE_DATA`` if set, else ``../shared/data`` beside the repository."""
    env = os.environ.get("EQUIPOSE_DATA")
    if env:
        return pathlib.Path(env)
    return pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data"


def category_symmetry(category: str) -> str:
    """``continuous:z`` for rotationally symmetric categories, else ``none``."""
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


# Complete-shape categories built from another ModelNet category plus procedural closed cylinders (train/shapes.py):
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
    from .shapes import cylinder_proportions, cylinder_surface
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


def _bbox_diag(p: np.ndarray) -> float:
    return float(np.linalg.norm(p.max(0) - p.min(0)))


class ModelNetComplete:
    """Complete-shape samples (rotated ModelNet clouds), indexable; ``train`` draws a fresh rotation per access.

    Args:
        root, category, split: data location. ``num_points``: N fed to the model (FPS subset of the 1024).
        train: random rotation per draw (``rng``); else ``rotations_per_instance`` seeded rotations.
        limit: first ``limit`` instances only (tests, quick runs).
    """

    def __init__(self, root, category: str, split: str, num_points: int, train: bool, scale: float = MODELNET_SCALE,
                 rotations_per_instance: int = TEST_ROTATIONS, seed: int = TEST_SEED, limit: int | None = None):
        self.clouds, self.ids = load_complete(root, category, split, limit)          # [S, 1024, 3]
        self.category, self.split, self.train, self.scale = category, split, train, float(scale)
        self.num_points = int(num_points)
        self.diags = np.array([_bbox_diag(c) for c in self.clouds]) / self.scale
        self.reps = 1 if train else int(rotations_per_instance)
        # fixed test rotations and FPS starts, one per (instance, repetition)
        self.rotations = random_rotations(len(self.clouds) * self.reps, seed=seed)   # [S·reps, 3, 3]
        self.starts = np.random.default_rng(seed).integers(0, self.clouds.shape[1], len(self.rotations))
        self.rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return len(self.clouds) * self.reps

    def sample(self, i: int, rng: np.random.Generator | None = None) -> dict:
        """Sample ``i``; with ``rng`` (training) the rotation and the FPS start are drawn from it."""
        inst = i // self.reps
        cloud = self.clouds[inst] / self.scale                                        # [1024, 3] model units
        if rng is not None:
            R = random_rotations(1, seed=rng)[0]
            start = int(rng.integers(0, len(cloud)))
        else:
            R, start = self.rotations[i], int(self.starts[i])
        idx = farthest_point_order(cloud, self.num_points, start=start)              # [N]
        canon = cloud[idx]                                                            # [N, 3]
        return {"points": (canon @ R.T).astype(np.float32), "rotation": R, "translation": np.zeros(3),
                "diag": float(self.diags[inst]), "canonical": canon.astype(np.float32), "instance": inst}

    def __getitem__(self, i: int) -> dict:
        return self.sample(i, self.rng if self.train else None)

    def raw(self, i: int) -> dict:
        """Evaluation view of sample ``i`` in metres (file units): the full rotated cloud, GT pose, bbox diagonal."""
        inst = i // self.reps
        R = self.rotations[i]
        return {"points_m": (self.clouds[inst].astype(np.float64) @ R.T), "rotation": R, "translation_m": np.zeros(3),
                "diag_m": float(self.diags[inst] * self.scale), "instance": inst}


class RenderedPartial:
    """Rendered partial-depth samples from a cache written by ``equipose.train.render.render_dataset``.

    The cache (``.npz``) holds concatenated back-projected points (metres, camera frame, through ``equipose.crop``),
    per-view offsets, GT poses (metres) and per-instance bbox diagonals. Training re-draws the FPS start per access.
    """

    def __init__(self, cache_path, num_points: int, train: bool, seed: int = TEST_SEED, limit: int | None = None):
        z = np.load(cache_path, allow_pickle=False)
        self.points_all, self.offsets = z["points"], z["offsets"]                    # [ΣP, 3], [V+1]
        self.R, self.t = z["rotations"], z["translations"]                           # [V, 3, 3], [V, 3] metres
        self.diag_m, self.instance = z["diags"], z["instances"]                      # [V], [V]
        self.scale = float(z["scale"])
        self.category = str(z["category"])
        self.num_points, self.train = int(num_points), train
        n = len(self.R) if limit is None else min(limit, len(self.R))
        self.n = n
        self.starts = np.random.default_rng(seed).integers(0, 1 << 30, n)
        self.rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return self.n

    def sample(self, i: int, rng: np.random.Generator | None = None) -> dict:
        pts = self.points_all[self.offsets[i]:self.offsets[i + 1]].astype(np.float64) / self.scale   # [P, 3]
        if rng is not None:   # random subset before FPS so that repeated draws differ
            pts = pts[rng.permutation(len(pts))[: max(self.num_points * 4, 1)]]
            start = int(rng.integers(0, len(pts)))
        else:
            start = int(self.starts[i] % len(pts))
        idx = farthest_point_order(pts, self.num_points, start=start)
        x = pts[idx]                                                                   # [N, 3]
        R, t = self.R[i], self.t[i] / self.scale
        return {"points": x.astype(np.float32), "rotation": R, "translation": t, "diag": float(self.diag_m[i] / self.scale),
                "canonical": ((x - t) @ R).astype(np.float32), "instance": int(self.instance[i])}

    def __getitem__(self, i: int) -> dict:
        return self.sample(i, self.rng if self.train else None)

    def raw(self, i: int) -> dict:
        """Evaluation view of sample ``i`` in metres: the cropped points as the SDK produced them, GT pose, diagonal."""
        return {"points_m": self.points_all[self.offsets[i]:self.offsets[i + 1]].astype(np.float64),
                "rotation": self.R[i], "translation_m": self.t[i].astype(np.float64), "diag_m": float(self.diag_m[i]),
                "instance": int(self.instance[i])}


def make_dataset(root, category: str, mode: str, split: str, num_points: int, train: bool,
                 limit: int | None = None, cache_dir=None, render_opts: dict | None = None):
    """The dataset for ``mode`` ('complete' | 'partial'); partial renders (or reuses) the seeded on-disk cache."""
    if mode == "complete":
        return ModelNetComplete(root, category, split, num_points, train, limit=limit)
    if mode == "partial":
        from .render import ensure_cache
        path = ensure_cache(root, category, split, cache_dir=cache_dir, limit=limit, **(render_opts or {}))
        return RenderedPartial(path, num_points, train)
    raise ConfigError(f"mode must be 'complete' or 'partial', got {mode!r}")


def collate(samples: list) -> dict:
    """Stack a list of samples into batched numpy arrays."""
    return {k: np.stack([s[k] for s in samples]) for k in samples[0]}
