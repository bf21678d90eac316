"""Training and evaluation datasets: ModelNet40 1024-point complete clouds and cached rendered partial-depth clouds.

The shape files are read by ``equipose.train.data.modelnet``; partial views come from
``equipose.train.data.render_cache``.

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

import numpy as np

from equipose.core.errors import ConfigError
from equipose.core.geometry import farthest_point_order, random_rotations
from equipose.train.data.modelnet import (MODELNET_SCALE, TEST_ROTATIONS, TEST_SEED, category_symmetry,  # noqa: F401
                                     default_data_root, load_complete, load_modelnet)

__all__ = ["ModelNetComplete", "RenderedPartial", "make_dataset", "collate"]


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
    """Rendered partial-depth samples from a cache written by ``equipose.train.data.render.render_dataset``.

    The cache (``.npz``) holds concatenated back-projected points (metres, camera frame, through
    ``equipose.preprocess``), per-view offsets, GT poses (metres) and per-instance bbox diagonals. Training re-draws
    the FPS start per access.
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
        return {"points": x.astype(np.float32), "rotation": R, "translation": t,
                "diag": float(self.diag_m[i] / self.scale),
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
        from equipose.train.data.render_cache import ensure_cache
        path = ensure_cache(root, category, split, cache_dir=cache_dir, limit=limit, **(render_opts or {}))
        return RenderedPartial(path, num_points, train)
    raise ConfigError(f"mode must be 'complete' or 'partial', got {mode!r}")


def collate(samples: list) -> dict:
    """Stack a list of samples into batched numpy arrays."""
    return {k: np.stack([s[k] for s in samples]) for k in samples[0]}
