"""Equivariance test harness shipped to users (numpy; works for torch modules and ONNX sessions alike).

Convention:
    A *model function* maps points [B, N, 3] float32 (model units) to a dict of numpy arrays with the ONNX contract
    names (``canonical_shape`` [B, M, 3], ``hypothesis_rotations`` [B, 60, 3, 3], ``hypothesis_translations``
    [B, 60, 3], ``hypothesis_scores`` [B, 60]) and optionally ``features`` [B, P, 60, C] (rotation axis 2) or
    [B, P, 12, C] (vertex descriptors of a quotient backbone; re-indexed by ``VERTEX_PERMUTATION``).
    Rotating the input by group element g (about the origin) must give: the same canonical shape; hypothesis j moved
    to index ``CAYLEY[g, j]`` as (g·R_j, g·t_j); scores and features re-indexed the same way. Translating the input
    by v must give the same canonical shape and every t_j shifted by v.

Use ``assert_equivariant(fn, points)`` in tests of any layer or model; ``torch_model_fn`` and ``onnx_model_fn``
adapt a torch module or an onnxruntime session to a model function. ``posed_state`` builds the per-object state a
pipeline stage runs on (``equipose.runtime.stage``), for testing a stage on its own; ``MetadataSpec`` the model spec
a stage's ``build`` reads its metadata entry from.
"""
from __future__ import annotations

from typing import Callable, Iterable

import numpy as np

from equipose.core import icosahedral
__all__ = ["cup_view_points", "assert_equivariant", "equivariance_errors", "torch_model_fn", "torch_layer_fn", "onnx_model_fn",
           "posed_state", "MetadataSpec"]

ModelFn = Callable[[np.ndarray], dict]


def equivariance_errors(fn: ModelFn, points: np.ndarray, rotations: Iterable[int] | None = None,
                        translation: np.ndarray | None = None) -> dict:
    """Max abs error per output over the given group elements (default: all 60) and one translation.

    Returns ``{"canonical_shape", "hypothesis_rotations", "hypothesis_translations", "hypothesis_scores",
    ["features"], "translation_shape", "translation_t", "max"}`` (floats).
    """
    points = np.asarray(points, dtype=np.float32)
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"points must be [B, N, 3], got {points.shape}")
    base = fn(points)
    errs: dict = {}

    def upd(key, value):
        errs[key] = max(errs.get(key, 0.0), float(value))

    for g in (range(icosahedral.NUM_ROTATIONS) if rotations is None else rotations):
        Rg = icosahedral.ANCHORS[g].astype(np.float32)
        out = fn(points @ Rg.T)
        perm = icosahedral.CAYLEY[g]                                            # j ↦ index of A_g·A_j
        upd("canonical_shape", np.abs(out["canonical_shape"] - base["canonical_shape"]).max())
        upd("hypothesis_rotations", np.abs(out["hypothesis_rotations"][:, perm] - Rg @ base["hypothesis_rotations"]).max())
        upd("hypothesis_translations",
            np.abs(out["hypothesis_translations"][:, perm] - base["hypothesis_translations"] @ Rg.T).max())
        upd("hypothesis_scores", np.abs(out["hypothesis_scores"][:, perm] - base["hypothesis_scores"]).max())
        if "features" in base and "features" in out:                           # 60 rotations or 12 vertex descriptors
            fperm = perm if base["features"].shape[2] == icosahedral.NUM_ROTATIONS else icosahedral.VERTEX_PERMUTATION[g]
            upd("features", np.abs(out["features"][:, :, fperm] - base["features"]).max())
    v = np.array([0.3, -0.2, 0.5], np.float32) if translation is None else np.asarray(translation, np.float32)
    out = fn(points + v)
    errs["translation_shape"] = float(np.abs(out["canonical_shape"] - base["canonical_shape"]).max())
    errs["translation_t"] = float(np.abs(out["hypothesis_translations"] - base["hypothesis_translations"] - v).max())
    errs["max"] = max(errs.values())
    return errs


def assert_equivariant(fn: ModelFn, points: np.ndarray, rotations: Iterable[int] | None = None,
                       atol: float = 1e-4, translation: np.ndarray | None = None) -> dict:
    """Raise ``AssertionError`` naming the worst output if any equivariance error exceeds ``atol``; return errors."""
    errs = equivariance_errors(fn, points, rotations, translation)
    bad = {k: v for k, v in errs.items() if k != "max" and v > atol}
    if bad:
        raise AssertionError(f"equivariance violated (atol {atol}): " + ", ".join(f"{k}={v:.2e}" for k, v in bad.items()))
    return errs


def torch_model_fn(model, with_features: bool = True) -> ModelFn:
    """Adapt an ``equipose.train.EquiPoseNet`` (put in eval mode) to a numpy model function."""
    import torch

    model.eval()

    def fn(points):
        with torch.no_grad():
            out = model(torch.from_numpy(np.ascontiguousarray(points)), return_aux=with_features)
        keep = set(("canonical_shape", "hypothesis_rotations", "hypothesis_translations", "hypothesis_scores"))
        if with_features:
            keep.add("features")
        return {k: v.numpy() for k, v in out.items() if k in keep}

    return fn


def torch_layer_fn(layer_fwd) -> ModelFn:
    """Adapt a torch callable ``points [B, N, 3] → features [B, P, 60 | 12, C]`` (a layer stack) to a model function.

    The contract outputs are constant dummies, so the harness checks only the features' permutation. Use with
    ``translation=np.zeros(3)`` (a layer stack sees the points as given, not centred).
    """
    import torch

    def fn(points):
        with torch.no_grad():
            f = layer_fwd(torch.from_numpy(np.ascontiguousarray(points))).numpy()
        b = points.shape[0]
        return {"canonical_shape": np.zeros((b, 1, 3)), "hypothesis_rotations": np.zeros((b, 60, 3, 3)),
                "hypothesis_translations": np.zeros((b, 60, 3)), "hypothesis_scores": np.zeros((b, 60)),
                "features": f}

    return fn


def onnx_model_fn(session) -> ModelFn:
    """Adapt an ``onnxruntime.InferenceSession`` of an equipose model to a numpy model function (a format-2 graph's
    neighbourhoods and hypothesis scores computed as the runtime does, ``equipose.runtime.session.GraphIO``)."""
    from equipose.runtime.session import GraphIO

    io = GraphIO(session, dict(session.get_modelmeta().custom_metadata_map))

    def fn(points):
        return io.run(session, np.ascontiguousarray(points, dtype=np.float32))

    return fn


class MetadataSpec:
    """A stand-in model spec for ``Stage.build``: every metadata key holds ``value`` (None: absent); ``name`` as a
    ``ModelSpec``'s."""

    def __init__(self, value, name: str = "m"):
        self.value, self.name = value, name

    def get(self, key, default=None):
        return default if self.value is None else self.value


def posed_state(points, rotation, translation, *, canonical=None, symmetry: str = "none", up=None):
    """An ``ObjectState`` holding one chosen pose, as the stages after selection see it.

    Convention: ``points`` [N, 3] the model input (model units, centred camera frame); ``rotation`` [3, 3] category
    frame → that frame and ``translation`` [3] model units; ``canonical`` [M, 3] the canonical shape in the category
    frame (default: the points carried there by the pose); ``up`` None or a unit camera-frame direction.
    """
    from equipose.preprocess.sampling import PreparedPoints
    from equipose.runtime.hypotheses import select_hypothesis
    from equipose.runtime.stage import ObjectState
    x = np.asarray(points, np.float64)
    R, t = np.asarray(rotation, np.float64).reshape(3, 3), np.asarray(translation, np.float64).reshape(3)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"points must be [N, 3], got {x.shape}")
    canon = (x - t) @ R if canonical is None else np.asarray(canonical, np.float64)          # [M, 3]
    prep = PreparedPoints(model_points=x, centre_m=np.array([0.0, 0.0, 1.0]), scale=1.0,
                          order=np.arange(len(x)))
    state = ObjectState(prep=prep, R=R[None].copy(), t=t[None].copy(), scores=np.zeros(1), canonical=canon,
                        template=canon, symmetry=symmetry, calibrated=True, canonical_category=canon,
                        up=None if up is None else np.asarray(up, np.float64))
    state.selection = select_hypothesis(state.R, state.t, state.scores, symmetry=symmetry)
    state.set_pose(R, t)
    return state


def cup_view_points(seed: int = 0, upside_down: bool = False) -> np.ndarray:
    """[900, 3] points of a cup seen from above, for tests of open-top checks: its outer wall (radius 0.35 at the
    base widening to 0.45 at the rim, height 0–1, z up) and its inside floor near the base; ``upside_down``: the same
    body standing on its opening (z mirrored into 0–1), so the floor plate is what its top shows."""
    rng = np.random.default_rng(seed)
    th, z = rng.uniform(0.0, 2.0 * np.pi, 700), rng.uniform(0.0, 1.0, 700)
    r = 0.35 + 0.1 * z
    wall = np.c_[r * np.cos(th), r * np.sin(th), z]                            # [700, 3]
    a, rr = rng.uniform(0.0, 2.0 * np.pi, 200), 0.3 * np.sqrt(rng.uniform(0.0, 1.0, 200))
    floor = np.c_[rr * np.cos(a), rr * np.sin(a), np.full(200, 0.05)]         # [200, 3]
    cloud = np.r_[wall, floor]
    return cloud * [1.0, 1.0, -1.0] + [0.0, 0.0, 1.0] if upside_down else cloud

