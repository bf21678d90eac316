"""Partial-depth renderer: z-buffer rasterisation of triangle meshes and surfel splatting of point clouds, then the
SDK's own depth → crop → points path (``equipose.preprocess.crop_points``). The seeded on-disk cache of rendered
views is ``equipose.train.data.render_cache``.

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
the distance to its 4th nearest neighbour (capped at 1.5× the median), so neighbouring discs overlap and the front
surface has no holes through which back surfaces could leak. Discs seen nearly edge-on (|n·ray| < 0.15) are skipped.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from equipose.preprocess import crop_points
from equipose.core.errors import EquiposeError
from equipose.core.geometry import random_rotations
from equipose.train.data.sensor import apply_sensor

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
                return ((p1[..., 0] - p0[..., 0]) * (q[..., 1] - p0[..., 1])
                        - (p1[..., 1] - p0[..., 1]) * (q[..., 0] - p0[..., 0]))

            area = edge(a, b, c)                                                # [n, 1]
            ok_area = np.abs(area) > 1e-12
            area = np.where(ok_area, area, 1.0)
            l0, l1, l2 = edge(b, c, p) / area, edge(c, a, p) / area, edge(a, b, p) / area   # [n, m] barycentrics
            eps = -1e-9
            inside = ((l0 >= eps) & (l1 >= eps) & (l2 >= eps) & ok_area
                      & (px <= u1[chunk, None]) & (py <= w1[chunk, None]))
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
    two-sided). Radii: ``radius_factor`` × distance to the ``k_radius``-th nearest neighbour, capped at ``clip`` ×
    median.
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
    crop_max_points: int = 4096        # equipose.preprocess grid thinning before that subset (part of the cache key)


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


def occlude_patch(depth_mm: np.ndarray, mask: np.ndarray, rng: np.random.Generator) -> tuple:
    """Put a flat occluder in front of part of the object: a rectangle over 15–60 % of the mask's box (entering from
    a random side) at 2–10 cm before the object's nearest point. Returns (depth [H, W] uint16 mm, visible mask)."""
    rows, cols = np.nonzero(mask)
    if not len(rows):
        return depth_mm, mask
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    share = rng.uniform(0.15, 0.6)
    side = int(rng.integers(4))                                                 # 0 bottom, 1 top, 2 left, 3 right
    if side < 2:
        cut = int(round((r1 - r0) * share))
        rr, cc = ((r1 - cut, r1 + 40) if side == 0 else (r0 - 40, r0 + cut)), (c0 - 20, c1 + 20)
    else:
        cut = int(round((c1 - c0) * share))
        rr, cc = (r0 - 20, r1 + 20), ((c0 - 40, c0 + cut) if side == 2 else (c1 - cut, c1 + 40))
    patch = np.zeros_like(mask)
    patch[max(rr[0], 0):max(rr[1], 0), max(cc[0], 0):max(cc[1], 0)] = True
    near = int(depth_mm[mask].min()) - int(rng.uniform(20, 100))
    out = depth_mm.copy()
    out[patch] = max(near, 1)
    return out, mask & ~patch


def render_views(shape: dict, rng: np.random.Generator, views: int, settings: RenderSettings,
                 radius: float = 1.0, sensor=None, occluder: float = 0.0) -> list:
    """Render ``views`` random views and back-project each through ``equipose.preprocess.crop_points`` with the mask.

    ``sensor``: an ``equipose.train.data.sensor.SensorModel`` applied to each frame (None: clean depth);
    ``occluder``: the chance of an occluder in front of part of the object (``occlude_patch``; the mask keeps the
    visible part). Returns [(points [P, 3] float32 metres camera frame, R, t)]; views whose crop fails (object out of
    frame, too few points) are re-drawn (up to 5 tries each).
    """
    K = camera_matrix(settings.width, settings.height, settings.fov_y_deg)
    size = (settings.width, settings.height)
    out = []
    for _ in range(views):
        for _try in range(5):
            R, t = sample_pose(rng, settings, radius)
            depth, mask = render_frame(shape, R, t, K, size)
            if occluder and rng.random() < occluder:
                depth, mask = occlude_patch(depth, mask, rng)
            if sensor is not None:
                noisy = apply_sensor(np.where(depth > 0, depth / 1000.0, np.inf), rng, sensor)   # [H, W] m
                depth = np.round(noisy * 1000.0).astype(np.uint16)
                mask = mask & (depth > 0)
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
