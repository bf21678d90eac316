"""GraspNet-1Billion reader: one example folder (``meta.mat``, ``depth.png``, ``color.png``, optional ``label.png``,
as graspnet-baseline's ``doc/example_data``) or the dataset layout ``scene_XXXX/<camera>/{depth,rgb,label,meta}/NNNN``.

Convention:
    ``meta.mat``: ``poses`` [3, 4, N] object model → camera, metres; ``cls_indexes`` [N]; ``intrinsic_matrix`` [3, 3];
    ``factor_depth`` (depth PNG / factor_depth = metres). In the files ``cls_indexes`` are 1-based: cls_index =
    GraspNet object id + 1 = the object's pixel value in ``label.png`` (graspnet-baseline reads them so; checked on
    the shipped example, whose ids 1, 6, 9 are the cracker box 000, the banana 005 and the drill 008 in the colour
    image). Object keys (``graspnet.toml``) are the 0-based GraspNet object ids (000 cracker_box … 087).
    Without ``label.png`` an object has no mask and no box: it is skipped with that reason, never guessed.
"""
from __future__ import annotations

import functools
import pathlib

from equipose.core.errors import SourceError
from equipose.eval.datasets.frames import GTFrame, load_mat, meta_objects, read_depth_m, read_image

__all__ = ["scan", "load_frame"]

_META_KEYS = ("poses", "cls_indexes", "intrinsic_matrix", "factor_depth")


def scan(root) -> list:
    """Frames of a GraspNet folder: [(frame_id, loader)]; ``loader()`` returns a ``GTFrame``.

    Convention: ``root`` is an example folder holding ``meta.mat``, or any folder above ``<camera>/meta/NNNN.mat``
    (a scene, ``scenes/``, the dataset root). Raises ``SourceError`` when neither is found.
    """
    root = pathlib.Path(root)
    if not root.is_dir():
        raise SourceError(f"graspnet: {root} is not a folder")
    if (root / "meta.mat").is_file():
        paths = {n: root / f"{n}.png" for n in ("depth", "color", "label")}
        return [(root.name, functools.partial(load_frame, root / "meta.mat", paths, root.name))]
    metas = sorted(p for p in root.rglob("meta/*.mat") if p.parent.name == "meta")
    if not metas:
        raise SourceError(f"graspnet: {root} holds neither meta.mat nor <camera>/meta/NNNN.mat files")
    out = []
    for m in metas:
        cam = m.parent.parent                                                  # scene_XXXX/<camera>
        n = m.stem
        paths = {"depth": cam / "depth" / f"{n}.png", "color": cam / "rgb" / f"{n}.png",
                 "label": cam / "label" / f"{n}.png"}
        fid = f"{cam.parent.name}/{cam.name}/{n}"
        out.append((fid, functools.partial(load_frame, m, paths, fid)))
    return out


def load_frame(meta_path, paths: dict, frame_id: str) -> GTFrame:
    """One GraspNet frame. Convention: ``paths`` {"depth", "color", "label"} → files (color, label optional); see the
    module docstring. Raises ``SourceError``."""
    m = load_mat(meta_path, _META_KEYS, what="graspnet meta")
    label = read_image(paths["label"], what="graspnet label") if paths["label"].is_file() else None
    if label is not None and label.ndim != 2:
        raise SourceError(f"graspnet label: {paths['label']} must be one channel, got shape {label.shape}")
    K, scale, objs = meta_objects(m, meta_path, label, label_offset=0, key_offset=-1,
                                  missing=f"no {paths['label'].name} beside {pathlib.Path(meta_path).name}: "
                                          "no mask or box for this object (add the label image to evaluate it)")
    depth = read_depth_m(paths["depth"], scale, what="graspnet depth")
    rgb = read_image(paths["color"], what="graspnet color", unchanged=False) if paths["color"].is_file() else None
    if label is not None and label.shape != depth.shape:
        raise SourceError(f"graspnet: {paths['label']} is {label.shape}, the depth {depth.shape}; they must match")
    return GTFrame("graspnet", frame_id, depth, K, rgb, objs)
