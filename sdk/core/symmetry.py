"""Category symmetry: parsing the metadata string, distances between rotations modulo it, canonical representatives.

Convention:
    Rotations are [3, 3] (object → camera) acting on column vectors: ``x_cam = R @ x_obj + t``.
    Symmetry strings: ``"none"``, ``"continuous:<x|y|z>"`` (rotation about that object axis changes nothing),
    ``"discrete:<x|y|z><n>"`` (n-fold about that axis, e.g. ``discrete:z2``). ``HALF_TURNS[a]`` is the half turn
    about object axis ``a``: ``R @ HALF_TURNS[a]`` turns the pose about it.
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import MetadataError
from equipose.core.geometry import cross

__all__ = ["HALF_TURNS", "parse_symmetry", "symmetric_distance_deg", "canonicalise_rotation"]

HALF_TURNS = {"x": np.diag([1.0, -1.0, -1.0]), "y": np.diag([-1.0, 1.0, -1.0]),   # half turn about an object axis
              "z": np.diag([-1.0, -1.0, 1.0])}                                    # (R @ H turns the pose about it)
_AXES = {"x": 0, "y": 1, "z": 2}


def parse_symmetry(symmetry: str):
    """``symmetry`` string → (kind, axis index or None, order). kind ∈ {"none", "continuous", "discrete"}."""
    if symmetry in (None, "", "none"):
        return "none", None, 1
    kind, _, spec = str(symmetry).partition(":")
    if kind == "continuous" and spec in _AXES:
        return "continuous", _AXES[spec], 0
    if kind == "discrete" and len(spec) >= 2 and spec[0] in _AXES and spec[1:].isdigit() and int(spec[1:]) >= 1:
        return "discrete", _AXES[spec[0]], int(spec[1:])
    raise MetadataError(f"unsupported symmetry {symmetry!r}; this SDK reads 'none', 'continuous:<x|y|z>' and "
                        "'discrete:<x|y|z><n>' (e.g. discrete:z2)")


def _axis_rotations(axis: int, order: int) -> np.ndarray:
    """[order, 3, 3] rotations by 2πk/order about object axis ``axis``."""
    out = np.zeros((order, 3, 3))
    for k in range(order):
        a = 2 * np.pi * k / order
        c, s = np.cos(a), np.sin(a)
        i, j = (axis + 1) % 3, (axis + 2) % 3
        out[k, axis, axis] = 1.0
        out[k, i, i], out[k, i, j], out[k, j, i], out[k, j, j] = c, -s, s, c
    return out


def symmetric_distance_deg(R_ref, R_all, symmetry: str = "none") -> np.ndarray:
    """Angle between ``R_ref`` [3, 3] and each of ``R_all`` [A, 3, 3] modulo the category symmetry, degrees [A].

    none: geodesic angle. continuous about axis k: angle between the rotated symmetry axes (columns k).
    discrete n-fold about k: min over the n equivalent rotations ``R · S_m``.
    """
    R_ref = np.asarray(R_ref, np.float64)
    R_all = np.asarray(R_all, np.float64)
    kind, axis, order = parse_symmetry(symmetry)
    if kind == "continuous":
        c = np.clip(R_all[:, :, axis] @ R_ref[:, axis], -1.0, 1.0)              # [A]
        return np.degrees(np.arccos(c))
    if kind == "none":
        tr = np.einsum("aij,ij->a", R_all, R_ref)                               # [A] trace(R_refᵀ R)
        return np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))
    eq = R_all[:, None] @ _axis_rotations(axis, order)[None]                    # [A, S, 3, 3]
    tr = np.einsum("asij,ij->as", eq, R_ref)                                    # [A, S] trace(R_refᵀ · eq)
    c = np.clip((tr - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(c)).min(axis=1)                                 # [A]


def canonicalise_rotation(R, symmetry: str = "none", reference=(1.0, 0.0, 0.0)) -> np.ndarray:
    """One representative of a rotation's symmetry class (deterministic, for reporting and smoothing).

    Convention: ``R`` [3, 3] object → camera. continuous about axis k: the symmetry axis (column k) is kept; column
    k+1 becomes the camera ``reference`` direction projected onto the plane ⟂ the axis (camera y if the reference is
    parallel to the axis); column k+2 = col k × col k+1. discrete n-fold: the equivalent ``R · S_m`` whose column k+1
    is closest to ``reference``. none: R unchanged.
    """
    R = np.asarray(R, np.float64).reshape(3, 3)
    kind, axis, order = parse_symmetry(symmetry)
    if kind == "none":
        return R.copy()
    ref = np.asarray(reference, np.float64)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    if kind == "discrete":
        cands = R[None] @ _axis_rotations(axis, order)                          # [n, 3, 3]
        return cands[int(np.argmax(cands[:, :, i] @ ref))]
    a = R[:, axis]
    v = ref - (ref @ a) * a
    if np.linalg.norm(v) < 1e-6:
        ref = np.array([0.0, 1.0, 0.0])
        v = ref - (ref @ a) * a
    v /= np.linalg.norm(v)
    out = np.zeros((3, 3))
    out[:, axis], out[:, i], out[:, j] = a, v, cross(a, v)
    return out
