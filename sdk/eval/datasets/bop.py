"""BOP reader: a scene folder (``scene_camera.json``, ``scene_gt.json``, ``depth/``, ``mask_visib/``, optional
``rgb/``) or a split folder holding several scene folders.

Convention:
    ``scene_camera.json``: per image id ``cam_K`` (9 values, row-major) and ``depth_scale`` (depth PNG × depth_scale =
    millimetres). ``scene_gt.json``: per image id a list of {``cam_R_m2c`` 9 values row-major, ``cam_t_m2c`` [3] mm,
    ``obj_id``}: object model → camera. ``depth/NNNNNN.png``; ``mask_visib/NNNNNN_KKKKKK.png`` the visible mask of
    annotation KKKKKK (its index in the image's list); ``rgb/NNNNNN.{png,jpg}`` optional. Object keys = ``obj_id``
    (BOP ycbv: 1..21 = the YCB-Video classes in the same order, so ``ycbv.toml`` applies).
"""
from __future__ import annotations

import functools
import json
import pathlib

import numpy as np

from equipose.core.errors import SourceError
from equipose.eval.datasets.frames import (GTFrame, GTObject, check_intrinsics, check_pose, read_depth_m,
                                           read_image)

__all__ = ["scan", "load_frame", "scene_dirs"]


def scene_dirs(root) -> list:
    """Scene folders under ``root``: [root] when it holds ``scene_gt.json``, else its sub-folders that do (sorted).
    Raises ``SourceError`` when there are none."""
    root = pathlib.Path(root)
    if not root.is_dir():
        raise SourceError(f"bop: {root} is not a folder")
    if (root / "scene_gt.json").is_file():
        return [root]
    scenes = sorted(p.parent for p in root.glob("*/scene_gt.json"))
    if not scenes:
        raise SourceError(f"bop: no scene_gt.json in {root} nor in its sub-folders; give a BOP scene or split folder")
    return scenes


def _json(path: pathlib.Path) -> dict:
    if not path.is_file():
        raise SourceError(f"bop: {path} does not exist")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise SourceError(f"bop: {path} is not valid JSON ({e})") from None


def scan(root) -> list:
    """Frames of a BOP scene or split: [(frame_id "scene/image", loader)]; ``loader()`` returns a ``GTFrame``.

    Convention: image ids are the keys of ``scene_gt.json`` (sorted numerically). Raises ``SourceError``.
    """
    out = []
    for scene in scene_dirs(root):
        gt, cam = _json(scene / "scene_gt.json"), _json(scene / "scene_camera.json")
        for key in sorted(gt, key=lambda k: int(k)):
            if key not in cam:
                raise SourceError(f"bop: image {key} is in {scene}/scene_gt.json but not in scene_camera.json")
            out.append((f"{scene.name}/{int(key):06d}",
                        functools.partial(load_frame, scene, int(key), gt[key], cam[key])))
    return out


def load_frame(scene, image_id: int, annotations: list, camera: dict) -> GTFrame:
    """One BOP image. Convention: see the module docstring; translations become metres. Raises ``SourceError``."""
    scene = pathlib.Path(scene)
    where = f"bop {scene.name}/{image_id:06d}"
    if "cam_K" not in camera or "depth_scale" not in camera:
        raise SourceError(f"{where}: scene_camera.json needs cam_K and depth_scale, got {sorted(camera)}")
    K = check_intrinsics(camera["cam_K"], f"{where}: cam_K")
    depth = read_depth_m(scene / "depth" / f"{image_id:06d}.png", float(camera["depth_scale"]) / 1000.0,
                         what=f"{where} depth")
    rgb = None
    for ext in ("png", "jpg"):
        p = scene / "rgb" / f"{image_id:06d}.{ext}"
        if p.is_file():
            rgb = read_image(p, what=f"{where} rgb", unchanged=False)
            break
    objs = []
    for k, a in enumerate(annotations):
        if not all(f in a for f in ("cam_R_m2c", "cam_t_m2c", "obj_id")):
            raise SourceError(f"{where}: annotation {k} needs cam_R_m2c, cam_t_m2c and obj_id, got {sorted(a)}")
        R, t = check_pose(a["cam_R_m2c"], np.asarray(a["cam_t_m2c"], np.float64) / 1000.0, f"{where} annotation {k}")
        mp = scene / "mask_visib" / f"{image_id:06d}_{k:06d}.png"
        mask, missing = None, None
        if mp.is_file():
            m = read_image(mp, what=f"{where} mask_visib")
            if m.shape[:2] != depth.shape:
                raise SourceError(f"{where}: {mp.name} is {m.shape}, the depth {depth.shape}; they must match")
            mask = (m if m.ndim == 2 else m[..., 0]) > 0
        else:
            missing = f"no mask_visib/{mp.name}: no mask or box for this object"
        objs.append(GTObject(key=int(a["obj_id"]), index=k, R=R, t=t, mask=mask, missing=missing))
    return GTFrame("bop", f"{scene.name}/{image_id:06d}", depth, K, rgb, objs)
