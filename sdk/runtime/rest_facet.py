"""The rest-facet stage of complete-shape models (metadata ``rest_facet``): "up" read off the shape itself.

A rigid object at rest stands on a facet of its convex hull (a car on the plane of its four wheels, a chair on its
legs' feet). For a complete cloud, the stage takes the network's up axis as a guess, looks for the hull facets whose
outward normal points down within ``tolerance_deg`` of it, merges coplanar ones and takes the largest: its inward
normal is "up", which then drives the up prior (``equipose.runtime.upright``) on the same network outputs. Not for
partial views: a single view's hull has facets where the view ends.

Convention: ``points`` [N, 3] any units, any frame (rotation-free use: directions come back in that frame);
``up_guess`` [3] unit in the same frame.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from equipose.core.geometry import cross

__all__ = ["REST_TOLERANCE_DEG", "rest_facet_up"]

REST_TOLERANCE_DEG = 20.0       # facets whose downward normal is this close to the network's "down" are candidates
_COPLANAR_DEG = 2.0             # facets this parallel ...
_COPLANAR_OFFSET = 0.01         # ... and this close (× the cloud's extent) form one face


def rest_facet_up(points, up_guess, tolerance_deg: float = REST_TOLERANCE_DEG) -> np.ndarray | None:
    """Unit [3] "up" of the largest hull face the object can rest on near ``up_guess``, or None (no such face, or a
    degenerate cloud)."""
    P = np.asarray(points, np.float64)
    u = np.asarray(up_guess, np.float64) / np.linalg.norm(up_guess)
    try:
        hull = ConvexHull(P)
    except (QhullError, ValueError):
        return None
    n, off = hull.equations[:, :3], hull.equations[:, 3]                        # [F, 3] outward unit, [F]
    tri = P[hull.simplices]                                                     # [F, 3, 3]
    area = 0.5 * np.linalg.norm(cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)      # [F]
    cand = np.nonzero(n @ -u > np.cos(np.radians(tolerance_deg)))[0]
    if len(cand) == 0:
        return None
    nc, oc, ac = n[cand], off[cand], area[cand]
    same = (nc @ nc.T > np.cos(np.radians(_COPLANAR_DEG))) & \
        (np.abs(oc[:, None] - oc[None]) < _COPLANAR_OFFSET * np.ptp(P, axis=0).max())   # [C, C]
    face_area = same.astype(np.float64) @ ac                                    # [C] area of each facet's face
    best = int(np.argmax(face_area))
    members = same[best]
    normal = (nc[members] * ac[members, None]).sum(0)                           # area-weighted face normal
    return -normal / np.linalg.norm(normal)
