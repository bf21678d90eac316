"""Geometric stages after hypothesis selection, switched on by model metadata: ``handle`` (full 6D from a mug's
observed handle, ``equipose.runtime.handle``) and ``shape_prior`` "cylinder" (the axis of cans and tins from the
observed normals, ``equipose.runtime.cylinder``).

Convention: ``model_points`` [N, 3] model input (model units, centred camera frame); ``translation`` [3] the chosen
pose's translation in the same frame; ``canonical_obj`` [M, 3] the canonical shape, category frame, model units.
"""
from __future__ import annotations

from equipose.runtime.cylinder import finish_cylinder
from equipose.runtime.handle import finish_handle

__all__ = ["apply_stages"]


def apply_stages(metadata: dict, result, model_points, translation, canonical_obj) -> None:
    """Run the stages the metadata asks for on a ``PoseResult`` (in place), cylinder axis first."""
    if metadata.get("shape_prior") == "cylinder":
        finish_cylinder(result, model_points)
    if metadata.get("handle") is not None:
        finish_handle(metadata["handle"], result, model_points, translation, canonical_obj)
