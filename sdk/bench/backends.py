"""Benchmark backends: a small registry of ways to run the network inside the SDK pipeline.

Convention:
    A backend is a ``Backend`` record: ``setup(est, frame, box, *, threads, checkpoint) -> (note, parity)`` swaps
    ``est.runner`` (model points [B, N, 3] model units → the four output arrays) for its own and may report a note on
    the weights and the max |Δ| against the ONNX file (None when not compared); ``model_file(path) -> path`` picks the
    file the ``PoseEstimator`` opens. This module registers the onnxruntime backends; torch-side backends live with
    the torch code (``PROVIDERS``: name → module that registers it when imported), so this module never imports them.
        onnxruntime-fp32  the model file through ``PoseEstimator``
        onnxruntime-int8  its ``.int8.onnx`` copy (``equipose.models.int8.ensure_int8``: built beside it, or in the
                          user cache for a read-only folder, when missing or out of date)
        torch             torch eager ``EquiPoseNet`` with the model's preset (``equipose.train.bench_backends``)
        icp60             ICP-60 against the model's canonical shape (``equipose.train.bench_backends``)
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass

__all__ = ["Backend", "BACKENDS", "PROVIDERS", "register_backend", "get_backend"]

# torch-side backends: name → the module that registers it (imported only when that backend is asked for)
PROVIDERS = {"torch": "equipose.train.bench_backends", "icp60": "equipose.train.bench_backends"}


@dataclass(frozen=True)
class Backend:
    name: str
    setup: object = None              # callable(est, frame, box, *, threads, checkpoint) -> (note, parity)
    model_file: object = None         # callable(model_path) -> path the estimator opens
    runs_model_file: bool = False     # the ONNX file itself runs (size and the adaptive thread policy apply)


_REGISTRY: dict = {}


def register_backend(name: str, setup=None, *, model_file=None, runs_model_file: bool = False) -> Backend:
    """Add (or replace) the backend ``name`` (see the module docstring for ``setup`` and ``model_file``)."""
    _REGISTRY[name] = Backend(name, setup, model_file, runs_model_file)
    return _REGISTRY[name]


def get_backend(name: str) -> Backend:
    """The registered backend ``name``, importing its provider module first if it is a torch-side one."""
    if name not in _REGISTRY and name in PROVIDERS:
        importlib.import_module(PROVIDERS[name])
    if name not in _REGISTRY:
        raise ValueError(f"backend must be one of {BACKENDS}, got {name!r}")
    return _REGISTRY[name]


def _int8_path(model_path: str) -> str:
    """The int8 copy of ``model_path`` (``equipose.models.int8``: built beside it, or in the user cache)."""
    from equipose.models.int8 import ensure_int8
    return str(ensure_int8(model_path))


register_backend("onnxruntime-fp32", runs_model_file=True)
register_backend("onnxruntime-int8", model_file=_int8_path, runs_model_file=True)

BACKENDS = tuple(_REGISTRY) + tuple(PROVIDERS)         # every known name, default order of ``run_benchmark``
