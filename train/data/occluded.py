"""Objects standing on a table behind an occluder, seen by a noisy depth sensor: the rendered set on which the
confidence is calibrated and the box prompt is checked against the mask prompt.

Convention:
    Object frame = the category frame (+z up), the object standing on the table plane z = min z of its points, origin
    at the shape's centre. The camera looks at the object from azimuth U(0, 2π), elevation U(15°, 60°), at a distance
    U(``distance_m``) metres; frames are OpenCV (x right, y down, z forward). Poses map object → camera,
    ``x_cam = R @ x_obj + t`` (metres). The occluder is an upright flat panel standing on the table between the camera
    and the object, U(1.2, 3)·r in front of it (r = the object's max radius; at most halfway to the camera), facing the
    camera, U(0.6, 2)·r wide, U(0.5, 1.4) times the height of the line of sight where it stands, shifted sideways by
    U(−1, 1)·r: it hides anything from nothing to most of the object. The depth frame passes
    through ``equipose.train.data.sensor.apply_sensor``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from equipose.eval.datasets.frames import mask_box
from equipose.train.data.render import camera_matrix, depth_to_uint16, splat_surfels
from equipose.train.data.scene import look_at_pose, table_surfels
from equipose.train.data.sensor import SensorModel, apply_sensor

__all__ = ["OccludedView", "render_occluded", "panel_surfels"]


@dataclass
class OccludedView:
    """One rendered frame. ``depth`` [H, W] uint16 mm (sensor model applied); ``mask`` [H, W] bool the object's
    visible pixels; ``full_mask`` its pixels without the occluder; ``box`` (x, y, w, h) of ``mask`` (a detector's
    box); ``K`` [3, 3]; ``R`` [3, 3], ``t`` [3] metres object → camera; ``occluded`` the hidden share of the object's
    pixels (0 without occluder); ``up`` [3] the table normal in the camera frame; ``part_pixels`` the visible pixels
    of the shape points ``render_occluded`` was given as ``part`` (e.g. a mug's handle; 0 without one)."""
    depth: np.ndarray
    mask: np.ndarray
    full_mask: np.ndarray
    box: tuple
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    occluded: float
    up: np.ndarray
    part_pixels: int = 0


def panel_surfels(centre: np.ndarray, right: np.ndarray, width: float, height: float, spacing: float) -> dict:
    """An upright rectangle (object frame): bottom edge centred on ``centre`` [3], spanning ``width`` along the unit
    horizontal ``right`` [3] and ``height`` along +z, as splat surfels {"points", "normals", "radii"}."""
    u = np.arange(-width / 2, width / 2 + 1e-9, spacing)
    v = np.arange(0.0, height + 1e-9, spacing)
    uu, vv = np.meshgrid(u, v)
    pts = centre + uu.reshape(-1, 1) * right + vv.reshape(-1, 1) * np.array([0.0, 0.0, 1.0])   # [P, 3]
    normal = np.cross(right, [0.0, 0.0, 1.0])
    return {"points": pts, "normals": np.tile(normal, (len(pts), 1)), "radii": np.full(len(pts), 0.75 * spacing)}


def render_occluded(shape: dict, rng: np.random.Generator, *, distance_m=(0.5, 1.2), occluder: float = 0.7,
                    sensor: SensorModel | None = SensorModel(), size=(640, 480), fov_y_deg: float = 60.0,
                    min_visible: float = 0.35, tries: int = 8, part=None, rest=None) -> OccludedView | None:
    """One view of a surfel ``shape`` ({"points", "normals", "radii"}, metres, category frame) on a table, with an
    occluder panel in front of it with probability ``occluder``. ``part``: optional [P] bool over the shape's points
    whose visible pixels the view counts (``part_pixels``: in front of everything else within 2 mm). ``rest``:
    optional [3, 3] rotation the object rests in on the table (category frame → table frame, e.g. a can lying on its
    side); None: standing upright. The view's ``R`` then includes it, and ``up`` stays the table normal.

    Views where less than ``min_visible`` of the object's pixels stay visible (or fewer than 150 pixels) are drawn
    again, up to ``tries`` times; returns None when none qualifies.
    """
    Q = np.eye(3) if rest is None else np.asarray(rest, np.float64)            # [3, 3] category → table frame
    pts = np.asarray(shape["points"], np.float64) @ Q.T                        # [P, 3] metres, resting
    normals = np.asarray(shape["normals"], np.float64) @ Q.T                   # [P, 3]
    r = float(np.linalg.norm(pts, axis=1).max())
    K = camera_matrix(size[0], size[1], fov_y_deg)
    z_table = float(pts[:, 2].min())
    for _ in range(tries):
        az, el = rng.uniform(0.0, 2 * np.pi), np.radians(rng.uniform(15.0, 60.0))
        dist = rng.uniform(*distance_m)
        R, t = look_at_pose(az, el, dist)                                      # object → camera
        d_obj = splat_surfels(pts @ R.T + t, normals @ R.T, shape["radii"], K, size)
        tab = table_surfels(z_table, max(3.0 * r, 0.4), max(0.03 * r, 0.004))
        d_tab = splat_surfels(tab["points"] @ R.T + t, tab["normals"] @ R.T, tab["radii"], K, size)
        d_occ = np.full_like(d_obj, np.inf)
        ground = dist * np.cos(el)                                              # horizontal camera distance
        if rng.random() < occluder and 0.5 * ground > 1.2 * r:                 # (a steep, near camera: no room)
            toward = np.array([np.cos(az), np.sin(az), 0.0])                   # horizontal, object → camera
            right = np.cross([0.0, 0.0, 1.0], toward)
            along = rng.uniform(1.2 * r, min(3.0 * r, 0.5 * ground))
            sight = -z_table + along * np.tan(el)                               # line of sight's height there
            centre = along * toward + rng.uniform(-1.0, 1.0) * r * right + np.array([0.0, 0.0, z_table])
            pan = panel_surfels(centre, right, rng.uniform(0.6, 2.0) * r, rng.uniform(0.5, 1.4) * sight,
                                max(0.02 * r, 0.002))
            d_occ = splat_surfels(pan["points"] @ R.T + t, pan["normals"] @ R.T, pan["radii"], K, size)
        full = np.isfinite(d_obj) & (d_obj <= d_tab)
        mask = full & (d_obj <= d_occ)
        n_full, n_vis = int(full.sum()), int(mask.sum())
        if n_vis < 150 or n_vis < min_visible * n_full:
            continue
        d = np.minimum(np.minimum(d_obj, d_tab), d_occ)                        # [H, W] m, inf = nothing
        part_px = 0
        if part is not None and np.any(part):
            sel = np.asarray(part, bool)
            d_part = splat_surfels(pts[sel] @ R.T + t, normals[sel] @ R.T,
                                   np.asarray(shape["radii"])[sel], K, size)
            part_px = int(np.count_nonzero(np.isfinite(d_part) & (d_part <= d + 0.002)))
        if sensor is not None:
            d = apply_sensor(d, rng, sensor)
        depth, _ = depth_to_uint16(np.where(d > 0, d, np.inf))
        mask = mask & (depth > 0)
        return OccludedView(depth=depth, mask=mask, full_mask=full, box=mask_box(mask), K=K, R=R @ Q, t=t,
                            occluded=1.0 - n_vis / max(n_full, 1), up=R[:, 2].copy(), part_pixels=part_px)
    return None
