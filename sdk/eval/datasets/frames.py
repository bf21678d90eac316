"""The common record of the dataset readers: one RGB-D frame with its ground-truth objects, and the checks and file
helpers the readers share.

Convention:
    Camera frame OpenCV (x right, y down, z forward), metres. ``depth_m`` [H, W] float32 metres (0 = invalid);
    ``K`` [3, 3] pinhole intrinsics of that image; ``rgb`` [H, W, 3] BGR uint8 or None. A ground-truth pose maps the
    dataset's *object model* frame to the camera: ``x_cam = R @ x_model + t`` (``R`` [3, 3], ``t`` [3] metres). An
    object's ``mask`` is [H, W] bool (its visible pixels) or None, and then ``missing`` says why there is none. Boxes are
    (x, y, w, h) pixels, the tight bounding box of the mask (what a detector would give).
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass, field

import numpy as np

from equipose.core.errors import SourceError

__all__ = ["GTObject", "GTFrame", "mask_box", "read_image", "read_depth_m", "check_intrinsics", "check_pose",
           "load_mat", "meta_objects"]


@dataclass
class GTObject:
    """One annotated object of a frame.

    Convention: ``key`` the dataset's object id as the mapping TOML keys it (YCB-Video / BOP ycbv: class id 1..21;
    GraspNet: object id 0..87); ``index`` its position in the frame's annotation list; ``R`` [3, 3] / ``t`` [3] metres
    model → camera; ``mask`` [H, W] bool or None (``missing``: the reason, e.g. "no label.png").
    """
    key: int
    index: int
    R: np.ndarray
    t: np.ndarray
    mask: np.ndarray | None = None
    missing: str | None = None


@dataclass
class GTFrame:
    """One RGB-D frame with its annotations. Convention: see the module docstring; ``frame_id`` is a readable id
    (e.g. "0048/000001"), ``dataset`` one of "ycbv", "bop", "graspnet"."""
    dataset: str
    frame_id: str
    depth_m: np.ndarray
    K: np.ndarray
    rgb: np.ndarray | None
    objects: list = field(default_factory=list)


def mask_box(mask) -> tuple | None:
    """Tight box (x, y, w, h) pixels of a [H, W] bool mask, or None when the mask is empty.

    Convention: x, y the top-left pixel; w, h in pixels (a one-pixel mask has w = h = 1).
    """
    m = np.asarray(mask, bool)
    if m.ndim != 2:
        raise SourceError(f"a mask must be [H, W], got shape {m.shape}")
    ys, xs = np.nonzero(m)
    if len(xs) == 0:
        return None
    return int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)


def read_image(path, *, what: str, unchanged: bool = True) -> np.ndarray:
    """An image file as numpy (``cv2.IMREAD_UNCHANGED`` by default: uint16 depth stays uint16).

    Convention: returns [H, W] or [H, W, 3] BGR. Raises ``SourceError`` naming ``what`` when the file is missing or
    unreadable.
    """
    import cv2
    p = pathlib.Path(path)
    if not p.is_file():
        raise SourceError(f"{what}: {p} does not exist")
    img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED if unchanged else cv2.IMREAD_COLOR)
    if img is None:
        raise SourceError(f"{what}: {p} is not a readable image")
    return img


def read_depth_m(path, metres_per_unit: float, *, what: str = "depth") -> np.ndarray:
    """A 16-bit depth PNG in metres.

    Convention: ``metres_per_unit`` > 0 (YCB-Video / GraspNet: 1 / factor_depth; BOP: depth_scale / 1000). Returns
    [H, W] float32 metres, 0 = invalid. Raises ``SourceError`` for a non-16-bit or multi-channel file.
    """
    d = read_image(path, what=what)
    if d.ndim != 2 or d.dtype != np.uint16:
        raise SourceError(f"{what}: {path} must be a one-channel uint16 PNG, got {d.dtype} {d.shape}")
    if not np.isfinite(metres_per_unit) or metres_per_unit <= 0:
        raise SourceError(f"{what}: the depth scale must be a positive number, got {metres_per_unit!r}")
    return (d.astype(np.float32) * np.float32(metres_per_unit))


def check_intrinsics(K, where: str) -> np.ndarray:
    """[3, 3] float64 pinhole matrix (fx, fy > 0, last row 0 0 1); raises ``SourceError`` saying ``where``."""
    K = np.asarray(K, np.float64)
    if K.size != 9:
        raise SourceError(f"{where}: intrinsics must have 9 values (3 x 3), got shape {K.shape}")
    K = K.reshape(3, 3)
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0 or not np.allclose(K[2], [0, 0, 1]):
        raise SourceError(f"{where}: not a pinhole matrix [[fx 0 cx] [0 fy cy] [0 0 1]]: {K.tolist()}")
    return K


def check_pose(R, t, where: str) -> tuple:
    """(R [3, 3], t [3]) float64 after checking R is a rotation (orthonormal, det +1 within 1e-3) and t is finite;
    raises ``SourceError`` saying ``where``."""
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64)
    if R.size != 9 or t.size != 3:
        raise SourceError(f"{where}: a pose needs R 3 x 3 and t 3 values, got {R.shape} and {t.shape}")
    R, t = R.reshape(3, 3), t.reshape(3)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise SourceError(f"{where}: the pose holds NaN/Inf")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-2 or np.linalg.det(R) < 0.99:
        raise SourceError(f"{where}: R is not a rotation (R Rᵀ ≠ I or det ≠ +1): {np.round(R, 4).tolist()}")
    return R, t


def load_mat(path, keys: tuple, *, what: str) -> dict:
    """A MATLAB ``.mat`` file (``scipy.io.loadmat``) with the required ``keys``; raises ``SourceError`` otherwise."""
    import scipy.io
    p = pathlib.Path(path)
    if not p.is_file():
        raise SourceError(f"{what}: {p} does not exist")
    try:
        m = scipy.io.loadmat(str(p))
    except Exception as e:                                                      # scipy raises several types
        raise SourceError(f"{what}: {p} is not a readable .mat file ({e})") from None
    miss = [k for k in keys if k not in m]
    if miss:
        raise SourceError(f"{what}: {p} lacks {miss} (it has {sorted(k for k in m if not k.startswith('__'))})")
    return m


def meta_objects(m: dict, path, label, *, label_offset: int, key_offset: int, missing: str) -> tuple:
    """The YCB-Video-style ``meta.mat`` fields → (K [3, 3], metres per depth unit, [GTObject]).

    Convention: ``poses`` [3, 4, N] (or [3, 4] for N = 1) object → camera, metres; ``cls_indexes`` [N]; object key =
    cls_index + ``key_offset``; its mask = ``label == cls_index + label_offset`` when ``label`` [H, W] is given, else
    None with the reason ``missing``.
    """
    K = check_intrinsics(m["intrinsic_matrix"], f"{path}: intrinsic_matrix")
    factor = float(np.asarray(m["factor_depth"]).ravel()[0])
    if not factor > 0:
        raise SourceError(f"{path}: factor_depth must be > 0, got {factor}")
    poses = np.asarray(m["poses"], np.float64)
    if poses.ndim == 2:
        poses = poses[:, :, None]
    cls = np.asarray(m["cls_indexes"]).astype(np.int64).ravel()
    if poses.shape[:2] != (3, 4) or poses.shape[2] != len(cls):
        raise SourceError(f"{path}: poses must be [3, 4, N] with N = len(cls_indexes) = {len(cls)}, got {poses.shape}")
    objs = []
    for i, c in enumerate(cls):
        R, t = check_pose(poses[:, :3, i], poses[:, 3, i], f"{path}: pose {i}")
        mask = None if label is None else (label == c + label_offset)
        objs.append(GTObject(key=int(c + key_offset), index=i, R=R, t=t, mask=mask,
                             missing=None if label is not None else missing))
    return K, 1.0 / factor, objs
