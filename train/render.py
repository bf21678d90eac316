"""Partial-depth renderer: z-buffer rasterisation of triangle meshes and surfel splatting of point clouds, then the
SDK's own depth → crop → points path (``equipose.crop.crop_points``), with a seeded on-disk cache.

Convention:
    Camera: OpenCV pinhole (x right, y down, z forward), pixel centres at integer coordinates; default 640×480,
    60° vertical fov ⇒ f = 240 / tan 30° ≈ 415.7 px, principal point (319.5, 239.5).
    Object pose: x_cam = R @ x_obj + t with R uniform on SO(3), t = (0, 0, d) + N(0, Σ), Σ = diag(0.2, 0.2, 0.15)
    (covariances, in the object's normalised units — max radius 1 — as the reference renderer; for metric meshes
    Σ is scaled by (radius)² so the framing is the same).
    Output frame: depth uint16 millimetres (0 = no surface), K [3, 3], mask [H, W] bool (pixels the object covers).
    Depth is the z coordinate (OpenCV depth), not the ray length.

Occlusion is exact per pixel: every primitive computes the depth of the pixel's ray at its own surface (triangles:
perspective-correct barycentric 1/z; surfels: ray-disc intersection) and the z-buffer keeps the nearest.

Point-only shapes are splatted as two-sided oriented discs (surfels): normals from the file (dense ModelNet clouds)
or, for the 1024-point clouds, by PCA of the 10 nearest neighbours; each disc's radius is ``radius_factor`` (1.0) ×
the distance to its 4th nearest neighbour (capped at 1.5× the median), so neighbouring discs overlap and the front surface has no holes through
which back surfaces could leak. Discs seen nearly edge-on (|n·ray| < 0.15) are skipped.
"""
from __future__ import annotations

import hashlib
import json
import math
import pathlib
import time
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import cKDTree

from equipose.crop import crop_points
from equipose.errors import ConfigError, EquiposeError
from equipose.geometry import random_rotations

__all__ = ["camera_matrix", "rasterize_mesh", "splat_surfels", "surfels_from_points", "depth_to_uint16",
           "RenderSettings", "sample_pose", "render_frame", "render_views", "ensure_cache", "CATEGORY_DISTANCE",
           "default_cache_dir", "render_mesh_cache", "write_partial_cache",
           "keyed_cache_path"]

# reference camera distances (spec §7), object normalised to max radius 1
CATEGORY_DISTANCE = {"airplane": 1.8, "car": 2.0, "bottle": 2.0, "bowl": 2.3, "sofa": 2.3, "chair": 2.3,
                     "cup": 2.0, "laptop": 2.0}
NEAR = 0.05


def camera_matrix(width: int = 640, height: int = 480, fov_y_deg: float = 60.0) -> np.ndarray:
    """Pinhole intrinsics [3, 3] for a vertical field of view (square pixels, centred principal point)."""
    f = (height / 2.0) / math.tan(math.radians(fov_y_deg) / 2.0)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])


def _zbuffer(pix: np.ndarray, z: np.ndarray, shape) -> np.ndarray:
    """Nearest depth per pixel: flat pixel indices [M] and depths [M] → [H, W] (inf where empty)."""
    buf = np.full(shape[0] * shape[1], np.inf)
    if len(pix):
        np.minimum.at(buf, pix, z)
    return buf.reshape(shape)


def _pow2(n: np.ndarray) -> np.ndarray:
    return (2 ** np.ceil(np.log2(np.maximum(n, 1)))).astype(np.int64)


def rasterize_mesh(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, size=(640, 480)) -> np.ndarray:
    """Depth (metres, inf = empty) [H, W] of a triangle mesh already in the camera frame.

    vertices [V, 3] camera frame metres; faces [F, 3] int. Triangles with a vertex closer than 5 cm are dropped
    (no near-plane clipping). Triangles are grouped by bounding-box size so each group is one vectorised
    barycentric test over its candidate pixels.
    """
    W, H = size
    v = np.asarray(vertices, np.float64)
    tri = v[np.asarray(faces, np.int64)]                                        # [F, 3, 3]
    tri = tri[(tri[..., 2] > NEAR).all(1)]
    z = tri[..., 2]                                                             # [F, 3]
    u = K[0, 0] * tri[..., 0] / z + K[0, 1] * tri[..., 1] / z + K[0, 2]        # [F, 3] pixel column
    w = K[1, 1] * tri[..., 1] / z + K[1, 2]                                     # [F, 3] pixel row
    u0 = np.clip(np.ceil(u.min(1)), 0, W).astype(np.int64)
    u1 = np.clip(np.floor(u.max(1)), -1, W - 1).astype(np.int64)
    w0 = np.clip(np.ceil(w.min(1)), 0, H).astype(np.int64)
    w1 = np.clip(np.floor(w.max(1)), -1, H - 1).astype(np.int64)
    keep = (u1 >= u0) & (w1 >= w0)
    u, w, z, u0, u1, w0, w1 = u[keep], w[keep], z[keep], u0[keep], u1[keep], w0[keep], w1[keep]
    bw, bh = _pow2(u1 - u0 + 1), _pow2(w1 - w0 + 1)
    pix_all, z_all = [], []
    for gw, gh in set(zip(bw.tolist(), bh.tolist())):
        sel = np.nonzero((bw == gw) & (bh == gh))[0]
        for chunk in np.array_split(sel, max(1, len(sel) * gw * gh // 4_000_000 + 1)):
            if len(chunk) == 0:
                continue
            oy, ox = np.mgrid[0:gh, 0:gw]
            px = u0[chunk, None] + ox.reshape(1, -1)                            # [n, gw·gh]
            py = w0[chunk, None] + oy.reshape(1, -1)
            a, b, c = (np.stack([u[chunk, k], w[chunk, k]], 1)[:, None, :] for k in range(3))   # [n, 1, 2]
            p = np.stack([px, py], -1).astype(np.float64)                       # [n, m, 2]

            def edge(p0, p1, q):
                return (p1[..., 0] - p0[..., 0]) * (q[..., 1] - p0[..., 1]) - (p1[..., 1] - p0[..., 1]) * (q[..., 0] - p0[..., 0])

            area = edge(a, b, c)                                                # [n, 1]
            ok_area = np.abs(area) > 1e-12
            area = np.where(ok_area, area, 1.0)
            l0, l1, l2 = edge(b, c, p) / area, edge(c, a, p) / area, edge(a, b, p) / area   # [n, m] barycentrics
            eps = -1e-9
            inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps) & ok_area & (px <= u1[chunk, None]) & (py <= w1[chunk, None])
            inv_z = l0 / z[chunk, 0, None] + l1 / z[chunk, 1, None] + l2 / z[chunk, 2, None]   # perspective-correct
            zz = 1.0 / np.where(inside, inv_z, 1.0)
            pix_all.append((py * W + px)[inside])
            z_all.append(zz[inside])
    if not pix_all:
        return np.full((H, W), np.inf)
    return _zbuffer(np.concatenate(pix_all), np.concatenate(z_all), (H, W))


def surfels_from_points(points: np.ndarray, normals: np.ndarray | None = None, radius_factor: float = 1.0,
                        k_radius: int = 4, k_normal: int = 10, clip: float = 1.5) -> tuple:
    """(normals [P, 3] unit, radii [P]) for surfel splatting of an object-frame cloud [P, 3].

    Normals: given ones (normalised) or PCA of the ``k_normal`` nearest neighbours (sign irrelevant: discs are
    two-sided). Radii: ``radius_factor`` × distance to the ``k_radius``-th nearest neighbour, capped at ``clip`` × median.
    """
    p = np.asarray(points, np.float64)
    tree = cKDTree(p)
    d, idx = tree.query(p, k=max(k_radius, k_normal) + 1)                      # [P, k+1]
    radii = d[:, k_radius]
    radii = radius_factor * np.minimum(radii, clip * np.median(radii))
    if normals is None:
        nb = p[idx[:, 1:k_normal + 1]] - p[:, None, :]                          # [P, k, 3]
        cov = np.einsum("pki,pkj->pij", nb, nb)                                 # [P, 3, 3]
        _, vecs = np.linalg.eigh(cov)
        normals = vecs[:, :, 0]                                                 # smallest eigenvalue
    n = np.asarray(normals, np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return n, radii


def splat_surfels(centres: np.ndarray, normals: np.ndarray, radii: np.ndarray, K: np.ndarray,
                  size=(640, 480), min_cos: float = 0.15) -> np.ndarray:
    """Depth (metres, inf = empty) [H, W] of two-sided discs in the camera frame (exact ray-disc intersection).

    centres [P, 3], normals [P, 3] unit, radii [P] (metres). Each disc touches the pixels of its projected bounding
    square, grouped by size for vectorisation.
    """
    W, H = size
    c, n, r = (np.asarray(a, np.float64) for a in (centres, normals, radii))
    ok = c[:, 2] - r > NEAR
    c, n, r = c[ok], n[ok], r[ok]
    uc = K[0, 0] * c[:, 0] / c[:, 2] + K[0, 1] * c[:, 1] / c[:, 2] + K[0, 2]
    vc = K[1, 1] * c[:, 1] / c[:, 2] + K[1, 2]
    rho = np.ceil(K[0, 0] * r / (c[:, 2] - r)).astype(np.int64) + 1             # pixel half-size of the window
    Kinv = np.linalg.inv(K)
    pix_all, z_all = [], []
    for g in np.unique(rho):
        sel = np.nonzero(rho == g)[0]
        oy, ox = np.mgrid[-g:g + 1, -g:g + 1]
        m = oy.size
        for chunk in np.array_split(sel, max(1, len(sel) * m // 3_000_000 + 1)):
            if len(chunk) == 0:
                continue
            px = np.round(uc[chunk])[:, None].astype(np.int64) + ox.reshape(1, -1)   # [n, m]
            py = np.round(vc[chunk])[:, None].astype(np.int64) + oy.reshape(1, -1)
            inimg = (px >= 0) & (px < W) & (py >= 0) & (py < H)
            ray = np.stack([px, py, np.ones_like(px)], -1).astype(np.float64) @ Kinv.T   # [n, m, 3], z = 1
            nd = np.einsum("nmi,ni->nm", ray, n[chunk])                        # n·d
            nc = np.einsum("ni,ni->n", n[chunk], c[chunk])[:, None]            # n·c
            cosang = np.abs(nd) / np.linalg.norm(ray, axis=-1)
            s = nc / np.where(np.abs(nd) > 1e-12, nd, 1e-12)                   # depth z of the hit
            hit = ray * s[..., None]                                           # [n, m, 3]
            inside = (np.sum((hit - c[chunk, None, :]) ** 2, -1) <= r[chunk, None] ** 2) & inimg & (s > NEAR) \
                & (cosang >= min_cos)
            pix_all.append((py * W + px)[inside])
            z_all.append(s[inside])
    if not pix_all:
        return np.full((H, W), np.inf)
    return _zbuffer(np.concatenate(pix_all), np.concatenate(z_all), (H, W))


def depth_to_uint16(depth_m: np.ndarray) -> tuple:
    """(depth uint16 mm [H, W] with 0 = empty, mask [H, W] bool)."""
    mask = np.isfinite(depth_m) & (depth_m > 0)
    mm = np.where(mask, np.round(np.where(mask, depth_m, 0) * 1000.0), 0)
    mask &= mm <= 65535
    return np.where(mask, mm, 0).astype(np.uint16), mask


@dataclass
class RenderSettings:
    """Camera and pose sampling (spec §7)."""
    width: int = 640
    height: int = 480
    fov_y_deg: float = 60.0
    distance: float = 1.8              # object-centre depth, in units of the object's max radius
    offset_var: tuple = (0.2, 0.2, 0.15)   # Σ diagonal (variances), same units squared
    max_points: int = 2048             # points kept per view in the cache (random subset of the crop)
    crop_max_points: int = 4096        # equipose.crop grid thinning before that subset (explicit: part of the cache key)


def sample_pose(rng: np.random.Generator, settings: RenderSettings, radius: float = 1.0) -> tuple:
    """(R [3, 3] uniform, t [3]) with t = radius · ((0, 0, d) + N(0, Σ)); depth kept ≥ 1.2 radius."""
    R = random_rotations(1, seed=rng)[0]
    t = np.array([0.0, 0.0, settings.distance]) + rng.normal(size=3) * np.sqrt(np.asarray(settings.offset_var))
    t[2] = max(t[2], 1.2)
    return R, t * radius


def render_frame(shape: dict, R: np.ndarray, t: np.ndarray, K: np.ndarray, size=(640, 480)) -> tuple:
    """Render one view of ``shape`` (``{"vertices", "faces"}`` or ``{"points", "normals", "radii"}``, object frame).

    Returns (depth uint16 mm [H, W], mask [H, W] bool).
    """
    if "faces" in shape:
        depth = rasterize_mesh(shape["vertices"] @ R.T + t, shape["faces"], K, size)
    else:
        depth = splat_surfels(shape["points"] @ R.T + t, shape["normals"] @ R.T, shape["radii"], K, size)
    return depth_to_uint16(depth)


def _modelnet_shapes(root, category: str, split: str, source: str, limit: int | None) -> list:
    """[(instance id, shape dict, complete points for the bbox)] in the normalised object frame (max radius 1)."""
    from .data import load_modelnet
    from .meshio import read_modelnet_txt
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


def render_views(shape: dict, rng: np.random.Generator, views: int, settings: RenderSettings,
                 radius: float = 1.0) -> list:
    """Render ``views`` random views and back-project each through ``equipose.crop.crop_points`` with the mask.

    Returns [(points [P, 3] float32 metres camera frame, R, t)]; views whose crop fails (object out of frame, too
    few points) are re-drawn (up to 5 tries each).
    """
    K = camera_matrix(settings.width, settings.height, settings.fov_y_deg)
    size = (settings.width, settings.height)
    out = []
    for _ in range(views):
        for _try in range(5):
            R, t = sample_pose(rng, settings, radius)
            depth, mask = render_frame(shape, R, t, K, size)
            try:
                crop = crop_points(depth, K, mask=mask, depth_unit="mm", max_points=settings.crop_max_points)
            except EquiposeError:
                continue
            pts = crop.points
            if len(pts) > settings.max_points:
                pts = pts[np.sort(rng.choice(len(pts), settings.max_points, replace=False))]
            out.append((pts.astype(np.float32), R, t))
            break
    return out


def render_mesh_cache(mesh_path, out_path, views: int = 10, distance_m: float = 0.6, seed: int = 0,
                      scale: float | None = None, category: str | None = None, settings: RenderSettings | None = None,
                      log=print) -> pathlib.Path:
    """Render ``views`` random views of one metric mesh (PLY/OBJ, metres) into an ``.npz`` cache (same layout as
    ``ensure_cache``). The mesh is centred at its vertex mean (the object frame's origin); the object centre is at
    ``distance_m`` (+ offsets Σ scaled by the max vertex radius²). ``scale`` defaults to 2 × max radius (max radius
    0.5 model units)."""
    from .meshio import read_mesh
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


def default_cache_dir() -> pathlib.Path:
    return pathlib.Path(__file__).resolve().parents[1] / "data_cache"


def ensure_cache(root, category: str, split: str, cache_dir=None, limit: int | None = None, views: int = 10,
                 source: str = "npy1024", seed: int = 0, settings: RenderSettings | None = None,
                 progress: bool = True, log=print) -> pathlib.Path:
    """Render (once) and cache the partial views of a ModelNet category split (tabletop categories: see
    ``equipose.train.tabletop``); returns the ``.npz`` path.

    The cache key hashes every setting, so a changed setting renders a new cache. Seeded per instance: view k of
    instance i depends only on (seed, split, i).
    """
    from tqdm import tqdm
    from .data import MODELNET_SCALE
    from .tabletop import ensure_tabletop_cache, is_tabletop
    if is_tabletop(category):     # cup / bowl / can: metric-scale tabletop data (equipose.train.tabletop)
        if settings is not None or source != "npy1024":
            raise ConfigError(f"tabletop category {category!r} renders with its own camera settings and sources "
                              "(equipose.train.tabletop); do not pass settings/source")
        return ensure_tabletop_cache(root, category, split, cache_dir=cache_dir, views=views, seed=seed,
                                     progress=progress, log=log, limit=limit)
    settings = settings or RenderSettings(distance=CATEGORY_DISTANCE.get(category, 2.0))
    key, path = keyed_cache_path(cache_dir, f"partial_{category}_{split}_{source}_v{views}",
                                 {"category": category, "split": split, "limit": limit, "views": views,
                                  "source": source, "seed": seed, "settings": asdict(settings), "v": 1})
    if path.is_file():
        return path
    shapes = _modelnet_shapes(root, category, split, source, limit)
    pts, Rs, ts, diags, inst = [], [], [], [], []
    t0 = time.perf_counter()
    split_id = 0 if split == "train" else 1
    for i, (cid, shape, complete) in enumerate(tqdm(shapes, desc=f"render {category}/{split}", disable=not progress)):
        rng = np.random.default_rng([seed, split_id, i])
        diag = float(np.linalg.norm(complete.max(0) - complete.min(0)))
        for p, R, t in render_views(shape, rng, views, settings):
            pts.append(p); Rs.append(R); ts.append(t); diags.append(diag); inst.append(i)
    dt = time.perf_counter() - t0
    if not pts:
        raise ConfigError(f"no view of {category}/{split} could be rendered")
    write_partial_cache(path, pts, Rs, ts, diags, inst, scale=MODELNET_SCALE, category=category, key=key, seconds=dt)
    log(f"rendered {len(pts)} views of {len(shapes)} {category}/{split} shapes in {dt:.1f} s "
        f"({len(pts) / dt:.1f} frames/s, render + crop) → {path}")
    return path


# Version of the render → crop pipeline whose output a cache holds; part of every cache key. Bump it whenever the
# renderer or ``equipose.crop`` changes the points it produces. 2: caches written before session 6 came from an older
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
