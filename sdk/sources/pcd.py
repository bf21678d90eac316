"""Organized PCD clouds (PCL / Kinect captures) as depth frames, via pypcd4.

Convention: an organized cloud (height > 1) with fields x, y, z in metres, camera frame, NaN = invalid, becomes
``depth`` [H, W] uint16 millimetres (0 = invalid) and ``K`` [3, 3] recovered by least squares from
``u = fx · x/z + cx``, ``v = fy · y/z + cy`` over the valid pixels (exact for a pinhole cloud). Colour fields ``rgb``
(packed float) or ``rgba`` (uint32) become ``rgb`` [H, W, 3] BGR uint8. ``binary_compressed`` (LZF) files are read.
``read_organized_cloud`` also returns the metric ``xyz`` [H, W, 3] and every other scalar field (e.g. ``label``) as
[H, W] arrays of the file's dtype.
"""
from __future__ import annotations

import pathlib
import warnings

import numpy as np

from equipose.core.errors import SourceError
from equipose.core.frame_error import FrameError
from equipose.sources.base import Frame, FrameSource, register_source

__all__ = ["PcdSource", "read_organized_pcd", "read_organized_cloud", "intrinsics_from_organized"]


def intrinsics_from_organized(xyz: np.ndarray) -> np.ndarray:
    """Pinhole K from an organized cloud. Convention: ``xyz`` [H, W, 3] metres (NaN invalid) → [3, 3] float64."""
    H, W, _ = xyz.shape
    valid = np.all(np.isfinite(xyz), axis=2) & (xyz[:, :, 2] > 0)             # [H, W]
    if valid.sum() < 100:
        raise SourceError(f"organized cloud has only {int(valid.sum())} valid points; cannot recover intrinsics")
    rows, cols = np.nonzero(valid)
    p = xyz[rows, cols].astype(np.float64)                                      # [P, 3]
    a, b = p[:, 0] / p[:, 2], p[:, 1] / p[:, 2]                                 # [P] normalised coordinates
    (fx, cx), res_u = np.linalg.lstsq(np.stack([a, np.ones_like(a)], 1), cols.astype(np.float64), rcond=None)[:2]
    (fy, cy), res_v = np.linalg.lstsq(np.stack([b, np.ones_like(b)], 1), rows.astype(np.float64), rcond=None)[:2]
    rms = float(np.sqrt((res_u.sum() + res_v.sum()) / (2 * len(p)))) if len(res_u) and len(res_v) else 0.0
    if not (fx > 0 and fy > 0) or rms > 2.0:
        raise SourceError(f"cloud is not a pinhole projection (fx={fx:.1f}, fy={fy:.1f}, reprojection rms {rms:.2f} px); "
                          "only organized camera clouds can be turned into depth frames")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def read_organized_cloud(path) -> dict:
    """Organized PCD file → dict. Raises ``SourceError``.

    Convention: keys ``xyz`` [H, W, 3] float32 metres, camera frame (NaN = invalid), ``depth`` [H, W] uint16 mm
    (0 = invalid), ``K`` [3, 3] float64, ``rgb`` [H, W, 3] BGR uint8 or None, ``fields`` {name: [H, W] array} for
    every other single-count field of the file (e.g. ``label`` uint32 of the mOSD clouds).
    """
    try:
        from pypcd4 import PointCloud
    except ImportError:
        raise SourceError("reading .pcd needs pypcd4 (a dependency of equipose): pip install pypcd4") from None
    path = pathlib.Path(path)
    try:
        with warnings.catch_warnings():                                         # numpy's "no data" warning: checked below
            warnings.simplefilter("ignore")
            pc = PointCloud.from_path(path)
    except FileNotFoundError:
        raise SourceError(f"{path} does not exist") from None
    except Exception as e:  # pypcd4 raises assorted errors for malformed headers/data
        raise SourceError(f"{path} is not a readable PCD file ({type(e).__name__}: {e})") from None
    fields = tuple(pc.fields)
    if not all(f in fields for f in ("x", "y", "z")):
        raise SourceError(f"{path} has fields {fields}; x, y, z are needed")
    W, H = int(pc.metadata.width), int(pc.metadata.height)
    if H <= 1:
        raise SourceError(f"{path} is an unorganized cloud ({W}×{H}); depth frames need an organized (image-shaped) "
                          "cloud — use PoseEstimator.predict_points on the points instead")
    n = len(pc.pc_data)                                                         # points actually read
    if n != W * H:                                                              # truncated or inconsistent header
        raise SourceError(f"{path} holds {n} points but its header declares WIDTH {W} × HEIGHT {H} = {W * H}; the "
                          "file is truncated or damaged — re-export it")
    try:
        return _organized_arrays(pc, fields, H, W)
    except (ValueError, TypeError, OverflowError) as e:                         # malformed field data
        raise SourceError(f"{path}: field data cannot be read as an organized cloud ({type(e).__name__}: {e})") from None


def _organized_arrays(pc, fields: tuple, H: int, W: int) -> dict:
    """pypcd4 cloud of H·W points → the arrays of ``read_organized_cloud``."""
    xyz = pc.numpy(("x", "y", "z")).astype(np.float32).reshape(H, W, 3)        # [H, W, 3] m
    K = intrinsics_from_organized(xyz)
    z = xyz[:, :, 2]
    valid = np.isfinite(z) & (z > 0)
    depth = np.zeros((H, W), np.uint16)
    depth[valid] = np.clip(np.round(z[valid] * 1000.0), 1, 65535).astype(np.uint16)
    rgb = None
    for name in ("rgb", "rgba"):
        if name in fields:
            raw = pc.numpy((name,)).reshape(-1)
            u = np.ascontiguousarray(raw).view(np.uint32) if raw.dtype == np.float32 else raw.astype(np.uint32)
            u = u.reshape(H, W)
            rgb = np.stack([(u & 255), (u >> 8) & 255, (u >> 16) & 255], axis=2).astype(np.uint8)  # BGR
            break
    extra = {}
    counts = dict(zip(fields, getattr(pc.metadata, "count", [1] * len(fields))))
    for name in fields:
        if name in ("x", "y", "z", "rgb", "rgba") or name.startswith("_") or counts.get(name, 1) != 1:
            continue
        extra[name] = pc.numpy((name,)).reshape(H, W)                          # [H, W] file dtype
    return {"xyz": xyz, "depth": depth, "K": K, "rgb": rgb, "fields": extra}


def read_organized_pcd(path) -> tuple:
    """PCD file → (depth [H, W] uint16 mm, K [3, 3], rgb [H, W, 3] BGR uint8 or None). Raises ``SourceError``."""
    cloud = read_organized_cloud(path)
    return cloud["depth"], cloud["K"], cloud["rgb"]


@register_source("pcd", suffixes=(".pcd",), folder=lambda p: bool(sorted(p.glob("*.pcd"))))
class PcdSource(FrameSource):
    """Frames from one organized ``.pcd`` file, a list of them, or a folder of them (sorted by name)."""

    def __init__(self, paths):
        if isinstance(paths, (str, pathlib.Path)):
            p = pathlib.Path(paths)
            paths = sorted(p.glob("*.pcd")) if p.is_dir() else [p]
        self.paths = [pathlib.Path(p) for p in paths]
        if not self.paths:
            raise SourceError("PcdSource got no .pcd files")
        missing = [str(p) for p in self.paths if not p.is_file()]
        if missing:
            raise SourceError(f"PCD file(s) not found: {', '.join(missing[:3])}")

    def __len__(self):
        return len(self.paths)

    def __iter__(self):
        for i, p in enumerate(self.paths):
            try:
                depth, K, rgb = read_organized_pcd(p)
            except SourceError as e:
                yield FrameError.from_exception(i, e)
                continue
            yield Frame(depth=depth, K=K, depth_unit="mm", rgb=rgb, index=i, name=p.stem)
