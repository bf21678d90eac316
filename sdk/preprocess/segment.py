"""Tabletop auto-crop for users without a detector: support plane + Euclidean clustering → object masks.

Convention: ``depth`` [H, W] in a declared unit, ``K`` [3, 3]; masks are [H, W] bool, largest object first.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from equipose.core.errors import EmptyDepthError
from equipose.core.geometry import cross
from equipose.preprocess.plane import densest_level, fit_plane_ransac
from equipose.preprocess.validate import check_intrinsics, depth_to_metres

__all__ = ["auto_masks"]


TABLE_SHARE = 0.3           # a parallel level above the dominant plane with this share of its points is the table
TABLE_HEIGHT_M = (0.2, 1.5)  # ... at a height in this range (m) above it


def table_level(heights: np.ndarray, plane_points: int, threshold: float) -> float:
    """Height (m) of a table top above the dominant plane, or 0.0 where there is none.

    Convention: ``heights`` [S] metres of the fit's sample points above the dominant plane (``plane_points`` of them
    on it, within ``threshold``). The most populated slice 2 × ``threshold`` high between ``TABLE_HEIGHT_M`` counts
    when it holds at least ``TABLE_SHARE`` × ``plane_points`` points: a floor with a table on it, seen from above.
    """
    lo, hi = TABLE_HEIGHT_M
    h = heights[(heights > lo) & (heights < hi)]
    if len(h) < TABLE_SHARE * plane_points or not len(h):
        return 0.0
    level, count = densest_level(h, lo, hi, 2 * threshold)
    return level if level is not None and count >= TABLE_SHARE * plane_points else 0.0


def auto_masks(depth, K, *, depth_unit="mm", image_size=None, min_depth: float = 0.1, max_depth: float = 3.0,
               plane_threshold: float = 0.012, min_height: float = 0.015, max_height: float = 0.5,
               cluster_radius: float = 0.02, min_cluster_points: int = 500, max_objects: int = 10,
               stride: int | None = None, table_hull: bool = True, merge_overlap: float = 0.5,
               seed: int = 0) -> list:
    """Tabletop auto-crop: dominant plane (RANSAC) + Euclidean clustering of what stands on it → object masks.

    Convention: ``depth`` [H, W] in ``depth_unit``; ``K`` [3, 3]. Returns a list of [H, W] bool masks, largest object
    first (possibly empty if nothing stands on the plane). The plane is fitted on ≤ 20k valid pixels; points between
    ``min_height`` and ``max_height`` above it are clustered (neighbours within ``cluster_radius`` m) on a pixel grid
    of ``stride`` (default: the stride whose spacing at the median depth is about ``cluster_radius`` / 2); every
    full-resolution pixel above the plane then joins the cluster of its nearest grid point (within
    ``cluster_radius``). With ``table_hull`` only points whose projection onto the plane falls inside the convex hull
    of the table inliers are kept (PCL's polygonal-prism idea: background beyond the table is ignored). Clusters
    touching the image border or smaller than ``min_cluster_points`` full-resolution pixels are dropped. Where the
    dominant plane is the floor and a table top parallel to it holds at least ``TABLE_SHARE`` as many points
    (``table_level``), the table is the plane.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    d = depth_to_metres(depth, depth_unit)                                      # [H, W] m
    H, W = d.shape
    Kf = check_intrinsics(K, (H, W), image_size)
    valid = (d >= min_depth) & (d <= max_depth)                                 # [H, W]
    rows, cols = np.nonzero(valid)                                              # [P]
    if len(rows) < 3 * min_cluster_points:
        raise EmptyDepthError(f"only {len(rows)} valid pixels within {min_depth}–{max_depth} m; auto crop needs a "
                              "table and objects in view")
    z = d[rows, cols]                                                           # [P] float32
    x = (cols.astype(np.float32) - np.float32(Kf[0, 2])) * z / np.float32(Kf[0, 0])
    y = (rows.astype(np.float32) - np.float32(Kf[1, 2])) * z / np.float32(Kf[1, 1])
    step = max(1, len(z) // 20000)
    sub = np.stack([x[::step], y[::step], z[::step]], 1).astype(np.float64)     # [≤20k, 3] for the plane fit
    n, off, inl = fit_plane_ransac(sub, threshold=plane_threshold, seed=seed)
    level = table_level(sub @ n + off, int(inl.sum()), plane_threshold)          # a table above the floor
    if level:
        off -= level
        inl = np.abs(sub @ n + off) < plane_threshold
    h = x * np.float32(n[0]) + y * np.float32(n[1]) + z * np.float32(n[2]) + np.float32(off)  # [P] height
    above = (h > min_height) & (h < max_height)                                 # [P]
    if table_hull and inl.sum() >= 3:
        from scipy.spatial import ConvexHull, QhullError
        e1 = cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = cross(n, e1)                                                       # (e1, e2) span the plane
        table2d = sub[inl] @ np.stack([e1, e2], 1)                              # [T, 2]
        try:
            eq = ConvexHull(table2d).equations                                  # [F, 3]: inside ⇔ a·q + b ≤ 0
            idx = np.nonzero(above)[0]
            q2d = np.stack([x[idx], y[idx], z[idx]], 1).astype(np.float64) @ np.stack([e1, e2], 1)  # [Q, 2]
            outside = np.any(q2d @ eq[:, :2].T + eq[:, 2] > 1e-9, axis=1)       # [Q]
            above[idx[outside]] = False                                         # outside the table's outline
        except QhullError:                                                      # degenerate (collinear) table
            pass
    rows, cols = rows[above], cols[above]
    pts = np.stack([x[above], y[above], z[above]], 1)                           # [Q, 3] m
    if len(rows) < min_cluster_points:
        return []
    if stride is None:
        stride = int(np.clip(round(Kf[0, 0] * cluster_radius / 2 / float(np.median(pts[:, 2]))), 1, 16))
    grid = (rows % stride == 0) & (cols % stride == 0)                          # [Q] subsample for clustering
    sp = pts[grid]                                                              # [S, 3]
    if len(sp) < 2:
        return []
    tree = cKDTree(sp)
    pairs = tree.query_pairs(cluster_radius, output_type="ndarray")             # [E, 2]
    S = len(sp)
    adj = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(S, S))
    _, lab_sub = connected_components(adj, directed=False)                      # [S]
    dist, nn = tree.query(pts, k=1, distance_upper_bound=cluster_radius)        # [Q]
    ok = np.isfinite(dist)
    labels = np.full(len(pts), -1, dtype=np.int64)                              # [Q]
    labels[ok] = lab_sub[nn[ok]]
    # hollow objects (cups, bowls) split into rim/inside and outside clusters: merge a cluster into a bigger one when
    # more than ``merge_overlap`` of its pixel bounding box lies inside the bigger one's box
    labs, counts = np.unique(labels[labels >= 0], return_counts=True)
    by_label = np.argsort(labels, kind="stable")                                # points grouped by label
    starts = np.searchsorted(labels[by_label], labs)                            # [C] first index of each label
    order = [k for k in np.argsort(-counts, kind="stable") if counts[k] >= min_cluster_points // 10]  # skip specks
    groups = []                                                                 # [[bbox r0, c0, r1, c1], [labels]]
    for k in order:
        sel = by_label[starts[k]:starts[k] + counts[k]]                         # indices of cluster k
        r, c = rows[sel], cols[sel]
        box = np.array([r.min(), c.min(), r.max() + 1, c.max() + 1])
        area = (box[2] - box[0]) * (box[3] - box[1])
        for g in groups:
            gb = g[0]
            inter = max(0, min(box[2], gb[2]) - max(box[0], gb[0])) * max(0, min(box[3], gb[3]) - max(box[1], gb[1]))
            if inter > merge_overlap * area:
                g[0] = np.array([min(box[0], gb[0]), min(box[1], gb[1]), max(box[2], gb[2]), max(box[3], gb[3])])
                g[1].append(labs[k])
                break
        else:
            groups.append([box, [labs[k]]])
    masks = []
    for box, members in groups:
        sel = np.isin(labels, members)
        if sel.sum() < min_cluster_points:
            continue
        if box[0] == 0 or box[1] == 0 or box[2] == H or box[3] == W:
            continue                                                            # cut by the image border
        m = np.zeros((H, W), dtype=bool)
        m[rows[sel], cols[sel]] = True
        masks.append(m)
    masks.sort(key=lambda m: -int(m.sum()))
    return masks[:max_objects]
