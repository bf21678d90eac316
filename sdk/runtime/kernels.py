"""The compiled (numba) kernels of the SDK, loaded or compiled once per process before the first frame.

numba compiles a kernel on its first call and caches the machine code next to its source (``__pycache__``); the
first process after an install compiles them all (30–60 s on a 2-core machine), later ones load them (about
0.3 s). ``PoseEstimator`` calls ``load_kernels()`` when it is built, so no frame pays for either and per-frame
timings stay those of the steady state.

Kernels: ICP (point-to-point and point-to-plane) and nearest neighbours (``equipose.core.icp``,
``equipose.core.nearest``), the network's neighbourhoods, kernel inputs and hypothesis scores
(``equipose.core.neighbourhoods``, ``equipose.core.kernel_weights``, ``equipose.core.scores``), farthest-point
sampling (``equipose.core.geometry``), RANSAC plane fit (``equipose.preprocess.plane``), the organized outlier
filter (``equipose.preprocess.crop``), the box prompt's surfaces (``equipose.preprocess.surfaces``), the mirror plane
of the frame priors (``equipose.runtime.frame_priors``), point normals (``equipose.core.normals``: the cylinder stage,
instance mode), the axis line of a body of revolution (``equipose.core.revolution``: the axis_centre stage), the
handle fit (``equipose.core.handles``), percentiles (``equipose.core.order_statistics``), the densified ICP template
(``equipose.runtime.template``), the open-top test (``equipose.core.opening``: the
confidence's evidence), hidden point removal (its spherical flip,
``equipose.runtime.visibility``, and convex hull, ``equipose.core.hull``: the view stage).
"""
from __future__ import annotations

import logging
import time

import numpy as np

__all__ = ["load_kernels"]

_log = logging.getLogger("equipose")
_loaded_s: float | None = None


def load_kernels() -> float:
    """Run every kernel once on a tiny input (compiling it, or loading it from the cache). Returns the seconds it
    took in this process (0.0 after the first call)."""
    global _loaded_s
    if _loaded_s is not None:
        return 0.0
    from equipose.core.geometry import farthest_point_order
    from equipose.core.handles import clustered_count, fit_handle, handle_zone_mask
    from equipose.core.icp import icp_multi, icp_point_to_plane
    from equipose.core.kernel_weights import kernel_inputs
    from equipose.core.neighbourhoods import (NeighbourhoodSpec, nearest_neighbourhoods, neighbourhood_specs,
                                              neighbourhoods)
    from equipose.core.presets import LayerSpec
    from equipose.core.revolution import axis_line
    from equipose.core.nearest import nearest_distances
    from equipose.core.neighbours import NearestNeighbours
    from equipose.core.normals import point_normals
    from equipose.core.opening import top_closure
    from equipose.core.order_statistics import selected_percentile
    from equipose.core.scores import hypothesis_scores
    from equipose.preprocess.crop import crop_points, organized_outlier_mask
    from equipose.preprocess.plane import find_support_plane, fit_plane_ransac
    from equipose.preprocess.sampling import prepare_points
    from equipose.preprocess.surfaces import box_object_cluster, surface_segments
    from equipose.runtime.frame_priors import mirror_plane
    from equipose.runtime.template import densify_template
    from equipose.runtime.visibility import visible_mask

    t0 = time.perf_counter()
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 3))
    for bidirectional in (False, True):
        icp_multi(x, x, np.eye(3)[None], np.zeros((1, 3)), iters=1, bidirectional=bidirectional)
    icp_multi(x, x[None], np.eye(3)[None], np.zeros((1, 3)), iters=1, hold=(2, [0.0, 0.0, 1.0]))
    icp_point_to_plane(x, x, np.tile([0.0, 0.0, 1.0], (len(x), 1)), np.eye(3)[None], np.zeros((1, 3)), iters=1)
    top_closure(x, [0.0, 0.0, 1.0], np.zeros(3))
    for brute_max in (0, 64):
        NearestNeighbours(x, brute_max=brute_max).query(x, guess=np.arange(len(x)))
        nearest_distances(x, x, brute_max)
    nearest_distances(x, x)                                                     # the SDK's calls: default size
    farthest_point_order(x, 8)
    visible_mask(x, np.array([0.0, 0.0, -5.0]))                                 # its flip and hull
    hypothesis_scores(x[None], x[None], np.eye(3)[None, None], np.zeros((1, 1, 3)), bidirectional=True)
    nearest_neighbourhoods(x[None], NeighbourhoodSpec(support=40, centres=8, k=4, ordered=True))
    layers = (LayerSpec(1, 4, 40, 8, 0.5, 0.1, 0.3, 4), LayerSpec(4, 4, 8, 8, 0.5, 0.1, 0.3, 4))
    x32 = x[None].astype(np.float32)
    nbh = neighbourhoods(x32, neighbourhood_specs(layers))
    kernel_inputs(x32, layers, nbh)                                            # format 3
    kernel_inputs(x32, layers, nbh, classes=(0, 1))                            # format 4: both class kernels
    prepare_points(x, 16, 1.0, min_points=8)
    fit_plane_ransac(np.c_[x[:, :2], np.zeros(len(x))])                        # a plane: the refit runs too
    find_support_plane(np.ones((8, 8), np.float32), np.array([[4.0, 0, 4], [0, 4.0, 4], [0, 0, 1]]), grid=1)
    grid = np.arange(16)
    organized_outlier_mask(rng.normal(size=(16, 3)), grid // 4, grid % 4)
    z = np.r_[np.full(8, 0.5), np.full(8, 0.8)]
    labels, cut = surface_segments(z, grid // 4, grid % 4, step=1, focal=100.0)
    box_object_cluster(z, grid // 4, grid % 4, (0, 0, 4, 4))                   # depth clusters, then surfaces
    box_object_cluster(z, grid // 4, grid % 4, (0, 0, 4, 4), labels=labels, cut=cut, points=np.c_[x[:16, :2], z],
                       focal=100.0)
    depth = np.full((48, 64), 900, np.uint16)                                   # a frame: a box on a wall
    depth[12:36, 16:48] = 700
    Kd = np.array([[60.0, 0.0, 32.0], [0.0, 60.0, 24.0], [0.0, 0.0, 1.0]])
    plane = (np.array([0.0, 0.0, -1.0]), 0.9)                                   # the wall
    for region in ({"box": (8, 8, 48, 32)}, {"box": (8, 8, 48, 32), "mask": depth < 800}, {"mask": depth < 800}):
        crop_points(depth, Kd, **region, support_plane=plane, max_points=256, min_points=8)
    mirror_plane(x, [1.0, 0.0, 0.0])
    point_normals(x)
    axis_line(x, point_normals(x), [0.0, 0.0, 1.0], np.zeros(3), iters=1)      # the axis_centre stage
    fit_handle(rng.normal(size=(60, 3)))
    handle_zone_mask(rng.normal(size=(60, 3)), rng.normal(size=(60, 3)), [1.0, 0.0, 0.0])
    clustered_count(x, np.arange(len(x)) < 4)
    selected_percentile(x[:, 0].copy(), 95.0)                                  # float64 heights (ObjectState)
    densify_template(x, 2)                                                      # the re-scoring's denser template
    _loaded_s = time.perf_counter() - t0
    if _loaded_s > 2.0:
        _log.info("compiled the geometry kernels in %.0f s (cached for later runs)", _loaded_s)
    return _loaded_s
