"""Was the handle seen? The visibility check of models whose pose includes a handle (metadata ``handle``).

Convention: model units, category frame (the handle along the metadata direction, z up). The observed points are the
model input moved into the category frame by the chosen pose; the handle zone is ``equipose.core.handles``'.
"""
from __future__ import annotations

import numpy as np

from equipose.core.handles import HANDLE_MIN_FRACTION, HANDLE_MIN_POINTS, handle_zone_count

__all__ = ["observe_handle"]


def observe_handle(direction, model_points, canonical_obj, rotation, translation) -> tuple:
    """(visible, count): whether ≥ max(``HANDLE_MIN_POINTS``, ``HANDLE_MIN_FRACTION``·N) observed points lie in the
    handle zone of the canonical shape.

    Convention: ``direction`` [3] category frame; ``model_points`` [N, 3] model input (model units, centred camera
    frame); ``canonical_obj`` [M, 3] canonical shape in the category frame, model units; ``rotation`` [3, 3] and
    ``translation`` [3] (model units) the chosen pose, category → centred camera frame.
    """
    P = np.asarray(model_points, np.float64)                                  # [N, 3]
    observed = (P - np.asarray(translation, np.float64)) @ np.asarray(rotation, np.float64)   # [N, 3] category frame
    count = handle_zone_count(observed, canonical_obj, direction)
    return bool(count >= max(HANDLE_MIN_POINTS, HANDLE_MIN_FRACTION * len(P))), count
