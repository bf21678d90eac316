"""Geometric stages after hypothesis selection, switched on by model metadata: ``flip_templates`` (front/back from
category templates, ``equipose.runtime.flip``), ``handle`` (full 6D from a mug's observed handle,
``equipose.runtime.handle``) and ``shape_prior`` "cylinder" (the axis of cans and tins from the observed normals,
``equipose.runtime.cylinder``).

Convention: ``model_points`` [N, 3] model input (model units, centred camera frame); ``translation`` [3] the chosen
pose's translation in the same frame; ``canonical_obj`` [M, 3] the canonical shape, category frame, model units.
"""
from __future__ import annotations

from equipose.runtime.cylinder import finish_cylinder
from equipose.runtime.flip import finish_flip
from equipose.runtime.handle import finish_handle

__all__ = ["apply_stages"]


def apply_stages(metadata: dict, result, model_points, translation, canonical_obj, up=None) -> None:
    """Run the stages the metadata asks for on a ``PoseResult`` (in place): front/back, cylinder axis, handle.
    ``up``: the up prior's unit camera-frame direction, or None."""
    if metadata.get("flip_templates") is not None:
        ft = metadata["flip_templates"]
        finish_flip(ft["points"], result, model_points, translation, axes=ft["axes"], up=up,
                    partial=bool(metadata["partial"]))
    if metadata.get("shape_prior") == "cylinder":
        finish_cylinder(result, model_points)
    if metadata.get("handle") is not None:
        finish_handle(metadata["handle"], result, model_points, translation, canonical_obj)
