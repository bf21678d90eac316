"""Preprocessing: depth frame → validated, cropped, cleaned object points → the model's input.

One module per step: ``validate`` (units, intrinsics, regions), ``crop`` (region → object points), ``surfaces`` (the
object a box is drawn around), ``plane`` (support plane RANSAC), ``segment`` (tabletop auto-crop masks), ``sampling``
(FPS ordering, centring, scaling).
"""
from equipose.preprocess.crop import (CropResult, check_crop_options, crop_points, organized_outlier_mask,
                                      statistical_outlier_mask)
from equipose.preprocess.plane import find_support_plane, fit_plane_ransac, local_support_plane
from equipose.preprocess.sampling import MIN_POINTS, PreparedPoints, check_spread, fps_order, prepare_points
from equipose.preprocess.segment import auto_masks
from equipose.preprocess.surfaces import box_object_cluster, depth_clusters, nearest_depth_cluster, surface_segments
from equipose.preprocess.validate import (check_box, check_intrinsics, check_mask, check_points, check_regions,
                                          depth_to_metres, region_bounds)

__all__ = ["CropResult", "PreparedPoints", "MIN_POINTS", "depth_to_metres", "check_intrinsics", "check_box",
           "check_mask", "crop_points", "prepare_points", "check_points", "statistical_outlier_mask",
           "organized_outlier_mask", "nearest_depth_cluster", "box_object_cluster", "surface_segments",
           "depth_clusters", "auto_masks", "fit_plane_ransac", "fps_order",
           "find_support_plane", "local_support_plane", "check_regions", "region_bounds", "check_crop_options",
           "check_spread"]
