"""``equipose render``: render and cache partial-depth views of a ModelNet category (seeded, on disk).

Convention: views go through ``equipose.crop.crop_points`` (the deployment path); the cache is an ``.npz`` of points
in metres (camera frame), GT poses and bbox diagonals, keyed by a hash of every setting (see ``render.ensure_cache``).
"""
from __future__ import annotations

from .data import default_data_root
from .render import CATEGORY_DISTANCE, RenderSettings, ensure_cache


def add_arguments(p) -> None:
    p.add_argument("--category", default="airplane")
    p.add_argument("--split", choices=["train", "test"], default="train")
    p.add_argument("--views", type=int, default=10, help="views per instance (default 10; test uses 5)")
    p.add_argument("--source", choices=["npy1024", "dense"], default="npy1024",
                   help="1024-point clouds (all categories, surfels from PCA normals) or dense clouds with normals")
    p.add_argument("--limit", type=int, help="first K instances only")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--data-root", dest="data_root", help="default $EQUIPOSE_DATA or ../shared/data")
    p.add_argument("--cache-dir", dest="cache_dir", help="default data_cache/ in the repository")


def run(args) -> int:
    settings = RenderSettings(distance=CATEGORY_DISTANCE.get(args.category, 2.0))
    path = ensure_cache(args.data_root or default_data_root(), args.category, args.split, cache_dir=args.cache_dir,
                        limit=args.limit, views=args.views, source=args.source, seed=args.seed, settings=settings)
    print(f"cache: {path}")
    return 0
