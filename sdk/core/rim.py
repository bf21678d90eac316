"""The axis of an open container from the plane of its rim.

A bowl's rim is a circle in a plane perpendicular to its symmetry axis, and from above the seen part of the rim and
the upper wall form a ring band around the axis. The normal of the plane that fits the points of the top band (the
``band`` share of the object's extent along the current axis estimate) is the axis; taking the band again along the
new axis and refitting settles it in a few rounds. This reads the axis from geometry alone, where the network's
reading of a partial bowl is off by several degrees.

The fit is refused where a round's band holds fewer than ``MIN_RIM_POINTS`` points or the last round's band is not
flat (its smallest over middle singular value above ``max_flat``: a strip of wall, not a ring), and reports how far
it turned the axis.

Convention: ``points`` [N, 3] in any frame and unit; ``axis`` [3] a direction in that frame (normalised here), pointing
out of the opening; the fitted axis keeps that sense.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from equipose.core.errors import ConfigError, InvalidPointsError

__all__ = ["RimFit", "rim_axis", "RIM_BAND", "MIN_RIM_POINTS", "MAX_FLAT"]

RIM_BAND = 0.3              # the top share of the extent along the axis whose points fit the rim plane
MIN_RIM_POINTS = 24         # fewer band points than this: no fit
MAX_FLAT = 0.3              # the band's smallest / middle singular value above this: not a ring, no fit


@dataclass(frozen=True)
class RimFit:
    """``axis`` [3] unit (the sense of the start axis), ``turn`` (degrees from the start axis), ``points`` (band
    points of the last round), ``flat`` (their smallest / middle singular value: near 0 for a ring)."""
    axis: np.ndarray
    turn: float
    points: int
    flat: float


def rim_axis(points, axis, band: float = RIM_BAND, iters: int = 4, max_flat: float = MAX_FLAT) -> RimFit | None:
    """The axis normal to the plane of the top ``band`` of ``points`` along ``axis``, refitted ``iters`` times, or
    None where a round's band holds fewer than ``MIN_RIM_POINTS`` points or the last one is not flat (``max_flat``)."""
    p = np.asarray(points, np.float64)
    a0 = np.asarray(axis, np.float64).reshape(3)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidPointsError(f"rim_axis needs [N, 3] points, got shape {p.shape}")
    if not 0.0 < band < 1.0 or iters < 1:
        raise ConfigError(f"rim_axis needs band in (0, 1) and iters ≥ 1, got {band!r}, {iters!r}")
    a0 = a0 / np.linalg.norm(a0)
    a = a0
    for _ in range(int(iters)):
        h = p @ a                                                               # [N] height along the axis
        top = p[h >= h.max() - band * (h.max() - h.min())]                      # [B, 3] the top band
        if len(top) < MIN_RIM_POINTS:
            return None
        s, vt = np.linalg.svd(top - top.mean(0), full_matrices=False)[1:]      # [3], [3, 3]
        a = vt[2] if vt[2] @ a >= 0.0 else -vt[2]                               # [3] unit, the start's sense
    flat = float(s[2] / max(s[1], 1e-12))                                       # the last round's band
    if flat > max_flat:
        return None
    turn = float(np.degrees(np.arccos(np.clip(a @ a0, -1.0, 1.0))))
    return RimFit(a, turn, int(len(top)), flat)
