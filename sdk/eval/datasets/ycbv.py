"""YCB-Video reader: ``DIR/NNNNNN-{color,depth,label}.png`` + ``DIR/NNNNNN-meta.mat``.

Convention:
    ``meta.mat`` (scipy.io.loadmat): ``poses`` [3, 4, N] object model → camera, metres; ``cls_indexes`` [N] 1-based
    YCB-Video class ids (1 = 002_master_chef_can … 21 = 061_foam_brick; the keys of ``ycbv.toml``);
    ``intrinsic_matrix`` [3, 3]; ``factor_depth``: depth PNG value / factor_depth = metres. ``label.png``: pixel value =
    class id (0 background) — an object's mask. ``color.png`` is optional (overlays fall back to depth).
    ``scan(DIR)`` also accepts a folder of such folders (e.g. ``data/0048``, ``data/0049``).
"""
from __future__ import annotations

import functools
import pathlib

from equipose.core.errors import SourceError
from equipose.eval.datasets.frames import GTFrame, load_mat, meta_objects, read_depth_m, read_image

__all__ = ["scan", "load_frame"]


def scan(root) -> list:
    """Frames of a YCB-Video folder: [(frame_id, loader)] sorted by path; ``loader()`` returns a ``GTFrame``.

    Convention: ``root`` holds ``*-meta.mat`` files, or sub-folders that do. Raises ``SourceError`` when none exist.
    """
    root = pathlib.Path(root)
    if not root.is_dir():
        raise SourceError(f"ycbv: {root} is not a folder; give the folder holding NNNNNN-meta.mat files")
    metas = sorted(root.glob("*-meta.mat")) or sorted(root.glob("*/*-meta.mat"))
    if not metas:
        raise SourceError(f"ycbv: no NNNNNN-meta.mat in {root} (nor one folder below); is this a YCB-Video data folder?")
    out = []
    for m in metas:
        prefix = m.name[: -len("-meta.mat")]
        fid = prefix if m.parent == root else f"{m.parent.name}/{prefix}"
        out.append((fid, functools.partial(load_frame, m.parent, prefix, fid)))
    return out


def load_frame(folder, prefix: str, frame_id: str | None = None) -> GTFrame:
    """One YCB-Video frame ``folder/prefix-*``. Convention: see the module docstring. Raises ``SourceError``."""
    folder = pathlib.Path(folder)
    meta_path = folder / f"{prefix}-meta.mat"
    m = load_mat(meta_path, ("poses", "cls_indexes", "intrinsic_matrix", "factor_depth"), what="ycbv meta")
    label_path = folder / f"{prefix}-label.png"
    label = read_image(label_path, what="ycbv label") if label_path.is_file() else None
    if label is not None and label.ndim != 2:
        raise SourceError(f"ycbv label: {label_path} must be one channel (class ids), got shape {label.shape}")
    K, scale, objs = meta_objects(m, meta_path, label, label_offset=0, key_offset=0,
                                  missing=f"no {label_path.name}: no mask or box for this object")
    depth = read_depth_m(folder / f"{prefix}-depth.png", scale, what="ycbv depth")
    color = folder / f"{prefix}-color.png"
    rgb = read_image(color, what="ycbv color", unchanged=False) if color.is_file() else None
    if label is not None and label.shape != depth.shape:
        raise SourceError(f"ycbv: {label_path} is {label.shape}, the depth {depth.shape}; they must match")
    return GTFrame("ycbv", frame_id or prefix, depth, K, rgb, objs)
