"""Geometric stages after hypothesis selection, switched on by model metadata: ``flip_templates`` (front/back from
category templates, ``equipose.runtime.flip``), ``turn_classifier`` (front/back and upside down from a learned
scorer of the view, ``equipose.runtime.turn_classifier``; after the templates; with the up prior only about up),
``handle`` (full 6D from a mug's observed handle,
``equipose.runtime.handle``) and ``shape_prior`` "cylinder" (the axis of cans and tins from the observed normals,
``equipose.runtime.cylinder``).

Convention: ``model_points`` [N, 3] model input (model units, centred camera frame); ``translation`` [3] the chosen
pose's translation in the same frame; ``canonical_obj`` [M, 3] the canonical shape, category frame, model units.
"""
from __future__ import annotations

from equipose.runtime.cylinder import finish_cylinder
from equipose.runtime.flip import finish_flip
from equipose.runtime.handle import finish_handle
from equipose.runtime.turn_classifier import finish_turn

__all__ = ["apply_stages"]


def apply_stages(metadata: dict, result, model_points, translation, canonical_obj, up=None) -> None:
    """Run the stages the metadata asks for on a ``PoseResult`` (in place): front/back (templates, then the turn
    classifier), cylinder axis, handle.
    ``up``: the up prior's unit camera-frame direction, or None."""
    if metadata.get("flip_templates") is not None:
        ft = metadata["flip_templates"]
        finish_flip(ft["points"], result, model_points, translation, axes=ft["axes"], up=up,
                    partial=bool(metadata["partial"]))
    if metadata.get("turn_classifier") is not None:
        tc = metadata["turn_classifier"]
        axes = tc["axes"] if up is None else [a for a in tc["axes"] if a == "z"]   # the up prior holds x and y
        if axes:
            finish_turn(tc, result, model_points, translation, axes=axes)
    if metadata.get("shape_prior") == "cylinder":
        finish_cylinder(result, model_points)
    if metadata.get("handle") is not None:
        finish_handle(metadata["handle"], result, model_points, translation, canonical_obj)
