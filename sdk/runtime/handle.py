"""The handle stage of models whose pose includes a handle (metadata ``handle``, e.g. ``mug``).

The network of such a model fixes the symmetry axis; the azimuth about it comes from the observed points: moved into
the category frame by the chosen pose, their handle is found by ``equipose.core.handles.fit_handle`` (a body circle
fit per height band and the 30° window with most points outside it) and the pose is turned about the axis so the
handle lies along the metadata direction. No handle found → the network's azimuth is kept and the result says the
handle was not seen (``handle_visible`` False, ``ambiguous`` True).

Convention: model units, category frame (z up = the symmetry axis, the handle along the metadata direction [3]).
"""
from __future__ import annotations

import numpy as np

from equipose.core.handles import HANDLE_MAX_RATIO, HANDLE_MIN_MASS, HANDLE_MIN_SHARE, fit_handle, turn_about_z

__all__ = ["resolve_handle"]


def resolve_handle(direction, model_points, rotation, translation) -> tuple:
    """(rotation [3, 3], found, fit): the pose turned about its z axis so the observed handle lies along
    ``direction``.

    Convention: ``direction`` [3] category frame; ``model_points`` [N, 3] model input (model units, centred camera
    frame); ``rotation`` [3, 3] and ``translation`` [3] (model units) the chosen pose, category → centred camera frame.
    """
    R = np.asarray(rotation, np.float64)
    observed = (np.asarray(model_points, np.float64) - np.asarray(translation, np.float64)) @ R   # [N, 3] category
    fit = fit_handle(observed, min_share=HANDLE_MIN_SHARE, min_mass=HANDLE_MIN_MASS, centre=(0.0, 0.0),
                     max_ratio=HANDLE_MAX_RATIO)
    if not fit.has_handle:
        return R, False, fit
    d = np.asarray(direction, np.float64)
    return R @ turn_about_z(fit.azimuth - np.arctan2(d[1], d[0])), True, fit
