"""Tabletop categories at metric scale: ``cup`` (mugs and cups), ``bowl`` and ``can`` (cans and bottles), rendered as
partial depth from ModelNet40 clouds resized to real sizes plus the real-scanned OCRTOC and YCB meshes.

Convention:
    Object frame: the ModelNet40 category frame (up = +z, the symmetry axis), origin at the shape's centre. The metric
    meshes are z-up in their files (``shampoo`` lies along y and is turned up); they are centred at their vertex mean.
    Units: metres everywhere in the cache; the category's ``scale`` (metres per model unit) maps them to model units.
    Camera: the renderer's OpenCV pinhole (``equipose.train.data.render``); the object centre is 0.5–1.4 m away (the
    range of a tabletop RGB-D camera), laterally offset by N(0, (0.12·d)²) per axis; rotations uniform on SO(3).
    Splits: train = ModelNet train shapes + every metric mesh / scan (+ ``cylinders`` procedural closed cylinders of
    every proportion, ``train/data/shapes.py``); test = ModelNet test shapes only (their frame is
    the category frame, so they also serve calibration and the paper-style table). The metric meshes are never in test.
    The cache layout is ``equipose.train.data.datasets.RenderedPartial``'s.
"""
from __future__ import annotations

import pathlib
import time
from dataclasses import asdict, dataclass

import numpy as np

from equipose.core.errors import ConfigError

__all__ = ["TabletopSpec", "TABLETOP", "is_tabletop", "tabletop_sources", "modelnet_sources", "ensure_tabletop_cache"]


@dataclass(frozen=True)
class TabletopSpec:
    """One tabletop category: ModelNet source category and metric size range, extra metric meshes / scans, scale."""
    scale: float                                   # metres per model unit (≈ 2 × largest max radius expected)
    modelnet: str                                  # ModelNet40 category resized to metric sizes
    radius_m: tuple                                # (min, max) max radius in metres drawn per ModelNet instance
    meshes: tuple = ()                             # triangle meshes (metres): (path under data root, "none" | "y_up")
    scans: tuple = ()                              # YCB-Video model points (points.xyz, metres), splatted as surfels
    train_limit: int | None = None                 # ModelNet train shapes used (None = all)
    test_limit: int | None = None                  # ModelNet test shapes used
    cylinders: int = 0                             # procedural closed cylinders added to train (train/data/shapes.py)
    handle: bool = False                           # keep only cups with a handle, turned so it points to +x
    upside_down: bool = False                      # an open container: it also rests on its opening on a table
    notes: str = ""


_O = "ocrtoc_scanned_household"
_Y = "ycb_meshes_pybullet"
_P = "ycb_posecnn/models"
TABLETOP = {
    "cup": TabletopSpec(scale=0.16, modelnet="cup", radius_m=(0.045, 0.075),
                        meshes=((f"{_O}/mug/visual.ply", "none"), (f"{_O}/blue_cup/visual.ply", "none")),
                        scans=(f"{_P}/025_mug/points.xyz",), upside_down=True, notes="mugs and cups, handle or not"),
    "mug": TabletopSpec(scale=0.16, modelnet="cup", radius_m=(0.045, 0.075),
                        meshes=((f"{_O}/mug/visual.ply", "none"), (f"{_O}/blue_cup/visual.ply", "none")),
                        scans=(f"{_P}/025_mug/points.xyz",), handle=True, upside_down=True,
                        notes="mugs with a handle, full 6D: handle along +x (equipose.core.handles)"),
    "bowl": TabletopSpec(scale=0.2, modelnet="bowl", radius_m=(0.06, 0.1),
                         meshes=((f"{_O}/bowl/visual.ply", "none"), (f"{_O}/green_bowl/visual.ply", "none"),
                                 (f"{_O}/doraemon_bowl/visual.ply", "none")),
                         scans=(f"{_P}/024_bowl/points.xyz",), upside_down=True),
    "can": TabletopSpec(scale=0.25, modelnet="bottle", radius_m=(0.06, 0.125), train_limit=200, test_limit=40,
                        meshes=((f"{_Y}/YcbMasterChefCan/textured_simple_reoriented.obj", "none"),
                                (f"{_Y}/YcbTomatoSoupCan/textured_simple_reoriented.obj", "none"),
                                (f"{_Y}/YcbMustardBottle/textured_simple_reoriented.obj", "none"),
                                (f"{_O}/bleach_cleanser/visual.ply", "none"), (f"{_O}/shampoo/visual.ply", "y_up"),
                                (f"{_O}/conditioner/visual.ply", "none"), (f"{_O}/blue_moon/visual.ply", "none")),
                        scans=(f"{_P}/005_tomato_soup_can/points.xyz", f"{_P}/002_master_chef_can/points.xyz"),
                        cylinders=150, notes="cylindrical cans and bottles; the axis sign is not defined"),
}

SENSOR_OCCLUDER = 0.5       # share of sensor-model training views with an occluder in front of part of the object
_UP = {"none": np.eye(3), "y_up": np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])}   # y → z


def is_tabletop(category: str) -> bool:
    return category in TABLETOP


def tabletop_sources(root, category: str, split: str, seed: int = 0) -> list:
    """[(name, shape dict in metres (object frame), complete points [P, 3] metres)] for one category and split."""
    from equipose.core.handles import align_handle
    from equipose.train.data.meshio import read_mesh
    from equipose.train.data.render import surfels_from_points
    if category not in TABLETOP:
        raise ConfigError(f"{category!r} is not a tabletop category ({', '.join(TABLETOP)})")
    spec, root = TABLETOP[category], pathlib.Path(root)
    clouds, ids = modelnet_sources(root, category, split)
    rng = np.random.default_rng([seed, 0 if split == "train" else 1, 77])
    out = []
    for cid, p in zip(ids, clouds):
        p = p.astype(np.float64) * rng.uniform(*spec.radius_m)           # max radius 1 → metres
        n, r = surfels_from_points(p)
        out.append((f"modelnet/{cid}", {"points": p, "normals": n, "radii": r}, p))
    if split != "train":
        return out
    for rel, up in spec.meshes:
        path = root / rel
        if not path.is_file():
            raise ConfigError(f"tabletop mesh {path} is missing; check --data-root")
        V, F = read_mesh(path)
        V = (V - V.mean(0)) @ _UP[up].T
        if spec.handle:
            V = align_handle(V)
        out.append((rel, {"vertices": V, "faces": F}, V))
    for rel in spec.scans:
        path = root / rel
        if not path.is_file():
            raise ConfigError(f"tabletop scan {path} is missing; check --data-root")
        p = np.loadtxt(path)[:, :3]
        p = p - p.mean(0)
        if spec.handle:
            p = align_handle(p)
        n, r = surfels_from_points(p)
        out.append((rel, {"points": p, "normals": n, "radii": r}, p))
    if spec.cylinders:                                                   # tins and tubes of every proportion
        from equipose.train.data.shapes import cylinder_mesh, cylinder_proportions, cylinder_surface
        crng = np.random.default_rng([seed, 0, 78])
        for k, (r, h) in enumerate(cylinder_proportions(spec.cylinders, seed=[seed, 0, 79])):
            V, F = cylinder_mesh(r, h)
            out.append((f"procedural/cylinder_{k}", {"vertices": V, "faces": F}, cylinder_surface(r, h, 2048, crng)))
    return out


def modelnet_sources(root, category: str, split: str) -> tuple:
    """(ModelNet clouds [S, 1024, 3] at max radius 1, ids) of a tabletop category's split: its ModelNet source
    category, limited as the spec says; for a ``handle`` category only the cups with a handle, turned so it is +x."""
    from equipose.core.handles import align_handle, fit_handle
    from equipose.train.data.modelnet import load_modelnet
    spec = TABLETOP[category]
    clouds, ids = load_modelnet(root, spec.modelnet, split, spec.train_limit if split == "train" else spec.test_limit)
    if not spec.handle:
        return clouds, ids
    fits = [fit_handle(c) for c in clouds]
    keep = [k for k, f in enumerate(fits) if f.has_handle]
    aligned = [align_handle(clouds[k], fits[k]) for k in keep]
    aligned = [c / np.linalg.norm(c, axis=1).max() for c in aligned]                # turning keeps the max radius
    return np.stack(aligned).astype(np.float32), [ids[k] for k in keep]


def _views_for(name: str, views: int, split: str) -> int:
    """Metric meshes and scans are few, so each gets more views than a ModelNet instance (or a procedural shape)."""
    return views if name.startswith(("modelnet/", "procedural/")) or split != "train" else views * 8


def _spec_key(spec: TabletopSpec, split: str) -> dict:
    """The spec fields that decide a split's sources (procedural cylinders only enter train), for the cache key."""
    d = asdict(spec)
    if split != "train" or not spec.cylinders:
        d.pop("cylinders")
    if not spec.handle:
        d.pop("handle")
    else:
        d["handle_fit"] = 2                        # version of equipose.core.handles' rule
    return d


def ensure_tabletop_cache(root, category: str, split: str, cache_dir=None, views: int = 10, seed: int = 0,
                          distance_m: tuple = (0.5, 1.4), lateral: float = 0.12, progress: bool = True,
                          log=print, limit: int | None = None, sensor: bool = False) -> pathlib.Path:
    """Render (once) the partial views of a tabletop category split into a ``RenderedPartial`` cache; returns its path.

    ``views`` per ModelNet instance (8× that per metric mesh / scan in train). Seeded per source: view k of source i
    depends only on (seed, split, i). ``limit`` keeps the first K sources (tests, smoke runs). ``sensor``: every frame
    through the depth-sensor model (``equipose.train.data.sensor``) and half of them with an occluder in front of part
    of the object (``render.occlude_patch``): what a real tabletop camera sees.
    """
    from tqdm import tqdm
    from equipose.train.data.cache_io import keyed_cache_path, write_partial_cache
    from equipose.train.data.render import RenderSettings, render_views
    from equipose.train.data.sensor import SensorModel
    spec = TABLETOP.get(category)
    if spec is None:
        raise ConfigError(f"{category!r} is not a tabletop category ({', '.join(TABLETOP)})")
    key, path = keyed_cache_path(cache_dir, f"tabletop_{category}_{split}_v{views}",
                                 {"tabletop": category, "split": split, "views": views, "seed": seed,
                                  "distance_m": list(distance_m), "lateral": lateral, "limit": limit,
                                  "spec": _spec_key(spec, split), "settings": asdict(RenderSettings()), "v": 1}
                                 | ({"sensor": asdict(SensorModel()), "occluder": SENSOR_OCCLUDER} if sensor else {}))
    if path.is_file():
        return path
    sources = tabletop_sources(root, category, split, seed)[:limit]
    pts, Rs, ts, diags, inst = [], [], [], [], []
    t0 = time.perf_counter()
    split_id = 0 if split == "train" else 1
    for i, (name, shape, complete) in enumerate(tqdm(sources, desc=f"render {category}/{split} (tabletop)",
                                                    disable=not progress)):
        rng = np.random.default_rng([seed, split_id, i])
        radius = float(np.linalg.norm(complete, axis=1).max())
        diag = float(np.linalg.norm(complete.max(0) - complete.min(0)))
        for _ in range(_views_for(name, views, split)):
            d = float(rng.uniform(*distance_m))
            var = (lateral * d / radius) ** 2
            settings = RenderSettings(distance=d / radius, offset_var=(var, var, (0.05 / radius) ** 2))
            for p, R, t in render_views(shape, rng, 1, settings, radius=radius,
                                        sensor=SensorModel() if sensor else None,
                                        occluder=SENSOR_OCCLUDER if sensor else 0.0):
                pts.append(p)
                Rs.append(R)
                ts.append(t)
                diags.append(diag)
                inst.append(i)
    dt = time.perf_counter() - t0
    if not pts:
        raise ConfigError(f"no view of tabletop {category}/{split} could be rendered")
    write_partial_cache(path, pts, Rs, ts, diags, inst, scale=spec.scale, category=category, key=key, seconds=dt,
                        sources=np.array([s[0] for s in sources]))
    log(f"rendered {len(pts)} views of {len(sources)} tabletop {category}/{split} sources in {dt:.1f} s "
        f"({len(pts) / dt:.1f} frames/s) → {path}")
    return path
