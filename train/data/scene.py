"""Objects standing on a table, seen from above: depth frames with the table in them, for the up prior and any
tabletop measurement that needs the support plane in the frame.

Convention:
    World frame = object frame: the object's category frame (+z up) standing on the table plane z = min z of its
    points (its rest pose). The camera looks at the object's centre from azimuth ``a`` and elevation ``e`` above the
    table, at ``settings.distance`` × radius; its frame is OpenCV (x right, y down, z forward). Returned poses map
    object → camera, ``x_cam = R @ x_obj + t``. Units: those of the shape (metres at ``radius``).
"""
from __future__ import annotations

import numpy as np

from equipose.train.data.render import (RenderSettings, camera_matrix, depth_to_uint16, splat_surfels)

__all__ = ["look_at_pose", "table_surfels", "render_standing"]


def look_at_pose(azimuth: float, elevation: float, distance: float) -> tuple:
    """(R [3, 3], t [3]) object → camera for a camera at (azimuth, elevation) radians, ``distance`` from the origin,
    looking at the origin with the image "up" along +z of the object as far as possible (a level camera)."""
    eye = distance * np.array([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                               np.sin(elevation)])
    fwd = -eye / np.linalg.norm(eye)                                           # camera +z, object frame
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)                                              # camera +x
    down = np.cross(fwd, right)                                                 # camera +y
    R = np.stack([right, down, fwd])                                            # rows: camera axes → object → camera
    return R, -R @ eye


def table_surfels(z: float, half_size: float, spacing: float) -> dict:
    """A square table top at height ``z`` (object frame) as splat surfels: {"points", "normals", "radii"}."""
    g = np.arange(-half_size, half_size + 1e-9, spacing)
    xx, yy = np.meshgrid(g, g)
    pts = np.stack([xx.ravel(), yy.ravel(), np.full(xx.size, z)], 1)          # [T, 3]
    return {"points": pts, "normals": np.tile([0.0, 0.0, 1.0], (len(pts), 1)),
            "radii": np.full(len(pts), 0.75 * spacing)}


def render_standing(shape: dict, rng: np.random.Generator, *, settings: RenderSettings | None = None,
                    elevation_deg=(15.0, 60.0), radius: float = 1.0, table: bool = True) -> dict:
    """One view of a surfel ``shape`` (``{"points", "normals", "radii"}``, max radius 1) standing on a table.

    Returns {"depth" uint16 mm [H, W] (object + table), "mask" [H, W] bool (object pixels in front of the table),
    "K" [3, 3], "R" [3, 3], "t" [3] (object → camera, metres), "box" (x, y, w, h) of the mask}.
    """
    settings = settings or RenderSettings()
    K = camera_matrix(settings.width, settings.height, settings.fov_y_deg)
    size = (settings.width, settings.height)
    az = rng.uniform(0.0, 2 * np.pi)
    el = np.radians(rng.uniform(*elevation_deg))
    R, t = look_at_pose(az, el, settings.distance * radius)
    obj = {k: np.asarray(v, np.float64) * (radius if k != "normals" else 1.0) for k, v in shape.items()}
    d_obj = splat_surfels(obj["points"] @ R.T + t, obj["normals"] @ R.T, obj["radii"], K, size)    # [H, W] m
    d = d_obj                                                                   # [H, W] m, inf = empty
    if table:
        tab = table_surfels(float(obj["points"][:, 2].min()), 2.0 * radius, 0.03 * radius)
        d = np.minimum(d_obj, splat_surfels(tab["points"] @ R.T + t, tab["normals"] @ R.T, tab["radii"], K, size))
    mask = np.isfinite(d_obj) & (d_obj <= d)
    depth, _ = depth_to_uint16(d)
    rows, cols = np.nonzero(mask)
    box = (int(cols.min()), int(rows.min()), int(cols.max() - cols.min() + 1), int(rows.max() - rows.min() + 1)) \
        if len(rows) else None
    return {"depth": depth, "mask": mask, "K": K, "R": R, "t": t, "box": box}
