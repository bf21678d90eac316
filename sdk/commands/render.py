"""``equipose render``: render and cache partial-depth views of a ModelNet category (seeded, on disk).

Convention: views go through ``equipose.preprocess.crop_points`` (the deployment path); the cache is an ``.npz`` of points
in metres (camera frame), GT poses and bbox diagonals, keyed by a hash of every setting (see ``render.ensure_cache``).
"""
from __future__ import annotations


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
    p.add_argument("--mesh", help="render one metric mesh (.ply/.obj, metres) instead of a ModelNet split")
    p.add_argument("--distance-m", dest="distance_m", type=float, default=0.6, help="--mesh: object depth (m)")
    p.add_argument("--out", help="--mesh: output .npz (default data_cache/mesh_<name>_v<views>.npz)")


def run(args) -> int:
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.render import CATEGORY_DISTANCE, RenderSettings
    from equipose.train.data.render_cache import ensure_cache
    if args.mesh:
        import pathlib
        from equipose.train.data.cache_io import default_cache_dir
        from equipose.train.data.render_cache import render_mesh_cache
        name = pathlib.Path(args.mesh).parent.name
        out = args.out or (pathlib.Path(args.cache_dir) if args.cache_dir else default_cache_dir()) / f"mesh_{name}_v{args.views}.npz"
        print(f"cache: {render_mesh_cache(args.mesh, out, views=args.views, distance_m=args.distance_m, seed=args.seed)}")
        return 0
    settings = RenderSettings(distance=CATEGORY_DISTANCE.get(args.category, 2.0))
    path = ensure_cache(args.data_root or default_data_root(), args.category, args.split, cache_dir=args.cache_dir,
                        limit=args.limit, views=args.views, source=args.source, seed=args.seed, settings=settings)
    print(f"cache: {path}")
    return 0
