"""The rendered partial-view cache: render ModelNet (or tabletop) shapes once with ``equipose.train.data.render``
and keep the views on disk (``equipose.train.data.cache_io`` layout), keyed by every setting.

Convention: views are seeded per instance — view k of instance i depends only on (seed, split, i); points are model
units (file units / ``MODELNET_SCALE``), poses camera frame.
"""
from __future__ import annotations

import os
import pathlib
import time
from dataclasses import asdict

import numpy as np

from equipose.core.errors import ConfigError
from equipose.train.data.cache_io import keyed_cache_path, write_partial_cache
from equipose.train.data.modelnet import MODELNET_SCALE, load_modelnet
from equipose.train.data.render import CATEGORY_DISTANCE, RenderSettings, render_views, surfels_from_points
from equipose.train.data.tabletop import ensure_tabletop_cache, is_tabletop

__all__ = ["modelnet_shapes", "render_mesh_cache", "ensure_cache"]


def modelnet_shapes(root, category: str, split: str, source: str, limit: int | None) -> list:
    """[(instance id, shape dict, complete points for the bbox)] in the normalised object frame (max radius 1)."""
    from equipose.train.data.meshio import read_modelnet_txt
    out = []
    if source == "npy1024":
        clouds, ids = load_modelnet(root, category, split, limit)
        for cid, p in zip(ids, clouds):
            p = p.astype(np.float64)
            n, r = surfels_from_points(p)
            out.append((cid, {"points": p, "normals": n, "radii": r}, p))
    elif source == "dense":
        folder = pathlib.Path(root) / ("modelnet40_normal_resampled_airplane" if category == "airplane"
                                       else "modelnet40_normal_resampled_samples") / split
        files = sorted(folder.glob(f"{category}_*.txt.gz"))[:limit]
        if not files:
            raise ConfigError(f"no dense {category} clouds under {folder}")
        for f in files:
            p, nrm = read_modelnet_txt(f)
            p = p - p.mean(0)
            p /= np.linalg.norm(p, axis=1).max()
            n, r = surfels_from_points(p, nrm)
            out.append((f.name.split(".")[0], {"points": p, "normals": n, "radii": r}, p))
    else:
        raise ConfigError(f"unknown render source {source!r} (npy1024 | dense)")
    return out


def render_mesh_cache(mesh_path, out_path, views: int = 10, distance_m: float = 0.6, seed: int = 0,
                      scale: float | None = None, category: str | None = None, settings: RenderSettings | None = None,
                      log=print) -> pathlib.Path:
    """Render ``views`` random views of one metric mesh (PLY/OBJ, metres) into an ``.npz`` cache (same layout as
    ``ensure_cache``). The mesh is centred at its vertex mean (the object frame's origin); the object centre is at
    ``distance_m`` (+ offsets Σ scaled by the max vertex radius²). ``scale`` defaults to 2 × max radius (max radius
    0.5 model units)."""
    from equipose.train.data.meshio import read_mesh
    V, F = read_mesh(mesh_path)
    V = V - V.mean(0)
    radius = float(np.linalg.norm(V, axis=1).max())
    settings = settings or RenderSettings(distance=distance_m / radius)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    out = render_views({"vertices": V, "faces": F}, rng, views, settings, radius=radius)
    dt = time.perf_counter() - t0
    if not out:
        raise ConfigError(f"no view of {mesh_path} could be rendered")
    diag = float(np.linalg.norm(V.max(0) - V.min(0)))
    out_path = pathlib.Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    write_partial_cache(out_path, [o[0] for o in out], [o[1] for o in out], [o[2] for o in out], [diag] * len(out),
                        [0] * len(out), scale=scale or 2.0 * radius, seconds=dt, key=str(mesh_path),
                        category=category or pathlib.Path(mesh_path).parent.name)
    log(f"rendered {len(out)} views of {mesh_path} ({len(F)} triangles) in {dt:.1f} s ({len(out) / dt:.1f} frames/s, "
        f"render + crop) → {out_path}")
    return out_path


def _render_instance(job) -> list:
    """[(points, R, t)] of one instance; ``job`` = (generator seed, shape, views, settings)."""
    rng_seed, shape, views, settings = job
    return render_views(shape, np.random.default_rng(list(rng_seed)), views, settings)


def ensure_cache(root, category: str, split: str, cache_dir=None, limit: int | None = None, views: int = 10,
                 source: str = "npy1024", seed: int = 0, settings: RenderSettings | None = None,
                 progress: bool = True, log=print, workers: int | None = None, sensor: bool = False) -> pathlib.Path:
    """Render (once) and cache the partial views of a ModelNet category split (tabletop categories: see
    ``equipose.train.data.tabletop``); returns the ``.npz`` path.

    The cache key hashes every setting, so a changed setting renders a new cache. Seeded per instance: view k of
    instance i depends only on (seed, split, i), so ``workers`` processes (default: ``EQUIPOSE_RENDER_WORKERS`` or 1)
    render the same views.
    """
    from tqdm import tqdm
    if is_tabletop(category):     # cup / bowl / can: metric-scale tabletop data (equipose.train.data.tabletop)
        if settings is not None or source != "npy1024":
            raise ConfigError(f"tabletop category {category!r} renders with its own camera settings and sources "
                              "(equipose.train.data.tabletop); do not pass settings/source")
        return ensure_tabletop_cache(root, category, split, cache_dir=cache_dir, views=views, seed=seed,
                                     progress=progress, log=log, limit=limit, sensor=sensor)
    if sensor:
        raise ConfigError("the depth-sensor model renders tabletop categories only (cup, mug, bowl, can)")
    settings = settings or RenderSettings(distance=CATEGORY_DISTANCE.get(category, 2.0))
    key, path = keyed_cache_path(cache_dir, f"partial_{category}_{split}_{source}_v{views}",
                                 {"category": category, "split": split, "limit": limit, "views": views,
                                  "source": source, "seed": seed, "settings": asdict(settings), "v": 1})
    if path.is_file():
        return path
    shapes = modelnet_shapes(root, category, split, source, limit)
    pts, Rs, ts, diags, inst = [], [], [], [], []
    t0 = time.perf_counter()
    split_id = 0 if split == "train" else 1
    jobs = [((seed, split_id, i), shape, views, settings) for i, (_, shape, _) in enumerate(shapes)]
    workers = workers if workers is not None else os.environ.get("EQUIPOSE_RENDER_WORKERS", "1")
    if not str(workers).isdigit() or int(workers) < 1:
        raise ConfigError(f"render workers must be a whole number ≥ 1 (EQUIPOSE_RENDER_WORKERS), got {workers!r}")
    workers = int(workers)
    if workers > 1:                    # same views: each instance's generator depends only on (seed, split, i)
        import multiprocessing
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            rendered = list(tqdm(pool.imap(_render_instance, jobs, chunksize=4), total=len(jobs),
                                 desc=f"render {category}/{split} ({workers} workers)", disable=not progress))
    else:
        rendered = (_render_instance(j) for j in tqdm(jobs, desc=f"render {category}/{split}", disable=not progress))
    for i, ((_, _, complete), views_i) in enumerate(zip(shapes, rendered)):
        diag = float(np.linalg.norm(complete.max(0) - complete.min(0)))
        for p, R, t in views_i:
            pts.append(p)
            Rs.append(R)
            ts.append(t)
            diags.append(diag)
            inst.append(i)
    dt = time.perf_counter() - t0
    if not pts:
        raise ConfigError(f"no view of {category}/{split} could be rendered")
    write_partial_cache(path, pts, Rs, ts, diags, inst, scale=MODELNET_SCALE, category=category, key=key, seconds=dt)
    log(f"rendered {len(pts)} views of {len(shapes)} {category}/{split} shapes in {dt:.1f} s "
        f"({len(pts) / dt:.1f} frames/s, render + crop) → {path}")
    return path
