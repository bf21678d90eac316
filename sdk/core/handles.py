"""The handle of a mug: find it on a z-up cloud and turn the cloud about z so that the handle points along +x.

Convention:
    Input: an upright cup-like cloud [N, 3] (any unit), symmetry axis parallel to +z, as the ModelNet40 ``cup`` files
    and the OCRTOC / YCB mug meshes are stored. Output frame (the ``mug`` category frame): the same points turned
    about the z axis through the origin so that the handle's azimuth, seen from the fitted body axis, is 0 (+x).
    Nothing is translated: the origin stays the file's.

How: the body axis is a circle fit (algebraic, refit on the outer wall: points at 0.7–1.1× the per-height median
radius); each
point's excess radius over its height band's median, above 15 %, is binned by azimuth; the handle is the 30° window
with most excess. A cup "has a handle" when that window holds ≥ ``min_share`` of all the excess and the excess is
≥ ``min_mass`` per point — on the 99 ModelNet40 cups this keeps the clearly handled ones (checked by eye on a
top-down plot of every cup).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from equipose.core.errors import InvalidPointsError
from equipose.core.order_statistics import median, sorted_percentile, sorted_quantile

__all__ = ["HandleFit", "fit_handle", "align_handle", "turn_about_z", "handle_zone_count", "handle_zone_mask", "HANDLE_MIN_POINTS",
           "HANDLE_MIN_FRACTION", "HANDLE_MIN_SHARE", "HANDLE_MIN_MASS", "HANDLE_MAX_RATIO",
           "HANDLE_MIN_CLUSTERED", "HANDLE_ZONE_MARGIN", "clustered_count"]

HANDLE_MIN_SHARE = 0.5           # fit_handle's window share for a handle seen in a partial view (complete clouds: 0.45)
HANDLE_MIN_MASS = 0.008          # ... and excess per point (lower admits silhouette noise of real depth as handles)
HANDLE_MIN_POINTS = 4            # observed points inside the handle zone for the handle to count as seen ...
HANDLE_MIN_FRACTION = 0.01       # ... and at least this fraction of the observed points
HANDLE_MIN_CLUSTERED = 3         # ... of which at least this many lie in a cluster (``clustered_count``): a handle is
                                 # a surface, flying pixels at an occluder's edge are scattered
HANDLE_ZONE_MARGIN = 1.15        # a handle point lies beyond this × the body radius of its height band
HANDLE_MAX_RATIO = 2.6           # radius / body radius a handle reaches at most (training mugs: 1.58–2.45): points
                                 # farther out are something else (an occluder's edge, flying pixels)


def _height_bands(z: np.ndarray, bands: int) -> np.ndarray:
    """[bands + 1] edges of equal-count height bands of ``z`` (numpy's quantiles, compiled)."""
    return _quantiles(np.sort(np.asarray(z, np.float64)), np.linspace(0.0, 1.0, bands + 1))


@njit(cache=True)
def _quantiles(sorted_z, qs):
    out = np.empty(len(qs))
    for i in range(len(qs)):
        out[i] = sorted_quantile(sorted_z, qs[i])
    return out


@dataclass(frozen=True)
class HandleFit:
    azimuth: float          # radians, handle direction about +z measured from +x
    share: float            # fraction of the excess radius inside the handle's 30° window
    mass: float             # mean excess radius per point (relative to the body radius)
    centre: tuple           # (x, y) of the fitted body axis, input units
    has_handle: bool


def fit_handle(points: np.ndarray, *, bands: int = 6, bins: int = 36, min_share: float = 0.45,
               min_mass: float = 0.008, centre=None, max_ratio: float | None = None) -> HandleFit:
    """Handle azimuth of an upright cup cloud [N, 3] (see the module docstring). ``centre``: a first guess (x, y) of
    the body axis (default: the points' median; a posed partial view passes its origin). ``max_ratio``: points
    farther than this × their band's median radius from the axis count as no excess (None: no bound). One compiled
    pass."""
    p = np.ascontiguousarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 50:
        raise InvalidPointsError(f"fit_handle needs an [N ≥ 50, 3] cloud, got shape {p.shape}")
    c = (median(p[:, 0]), median(p[:, 1])) if centre is None else np.asarray(centre, np.float64).reshape(2)
    edges = _height_bands(p[:, 2], bands)                                          # [bands + 1]
    cap = np.inf if max_ratio is None else float(max_ratio)
    azimuth, share, mass, cx, cy = _fit_handle(p, edges, int(bins), float(c[0]), float(c[1]), cap)
    return HandleFit(azimuth, share, mass, (cx, cy), share >= min_share and mass >= min_mass)


@njit(cache=True)
def _band_radius(r, band, bands):
    """[N] the median of ``r`` [N] over each point's height band (an empty band: the median of all)."""
    med = np.empty(bands)
    for k in range(bands):
        sel = r[band == k]
        med[k] = np.median(sel) if len(sel) else np.median(r)
    return med[band]


@njit(cache=True)
def _fit_handle(p, edges, bins, cx, cy, cap) -> tuple:
    """(azimuth, share, mass, centre x, centre y) of ``fit_handle`` for the cloud ``p`` [N, 3] float64 with height
    band ``edges`` [bands + 1] (numpy's quantiles: numba's may differ in the last bit, which moves points between
    bands) and the excess bound ``cap`` (× band radius)."""
    bands = len(edges) - 1
    band = np.minimum(np.maximum(np.searchsorted(edges, p[:, 2]) - 1, 0), bands - 1)   # [N]
    N = len(p)
    r = np.empty(N)
    for _ in range(4):                                                         # circle fit on the outer wall
        for i in range(N):
            r[i] = np.sqrt((p[i, 0] - cx) ** 2 + (p[i, 1] - cy) ** 2)
        rb = _band_radius(r, band, bands)
        body = (r < 1.1 * rb) & (r > 0.7 * rb)                               # not the handle, nor the inside
        m = int(body.sum())
        if m < 10:
            break
        A, y = np.empty((m, 3)), np.empty(m)                                   # x² + y² = 2cx·x + 2cy·y + k
        j = 0
        for i in range(N):
            if body[i]:
                A[j, 0], A[j, 1], A[j, 2] = 2.0 * p[i, 0], 2.0 * p[i, 1], 1.0
                y[j] = p[i, 0] ** 2 + p[i, 1] ** 2
                j += 1
        sol = np.linalg.lstsq(A, y)[0]
        cx, cy = sol[0], sol[1]
    az = np.empty(N)
    for i in range(N):
        dx, dy = p[i, 0] - cx, p[i, 1] - cy
        r[i] = np.sqrt(dx * dx + dy * dy)
        az[i] = np.arctan2(dy, dx)                                             # radians
    ratio = r / np.maximum(_band_radius(r, band, bands), 1e-12)                # [N]
    excess = np.where(ratio <= cap, np.maximum(ratio - HANDLE_ZONE_MARGIN, 0.0), 0.0)   # [N]
    hist = np.zeros(bins)
    for i in range(N):
        hist[int((az[i] + np.pi) / (2 * np.pi) * bins) % bins] += excess[i]
    peak, best = 0, -1.0
    for b in range(bins):                                                      # 30° windows
        w = hist[b] + hist[(b - 1) % bins] + hist[(b + 1) % bins]
        if w > best:
            peak, best = b, w
    total = hist.sum()
    centre_az = -np.pi + (peak + 0.5) * 2 * np.pi / bins
    ws, wc, wsum = 0.0, 0.0, 0.0
    for i in range(N):
        delta = np.arctan2(np.sin(az[i] - centre_az), np.cos(az[i] - centre_az))
        if abs(delta) < np.radians(30.0):
            ws += excess[i] * np.sin(az[i])
            wc += excess[i] * np.cos(az[i])
            wsum += excess[i]
    azimuth = np.arctan2(ws, wc) if wsum > 0 else 0.0
    share = best / total if total > 0 else 0.0
    return azimuth, share, total / N, cx, cy


def turn_about_z(angle: float) -> np.ndarray:
    """[3, 3] rotation by ``angle`` radians about +z."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def align_handle(points: np.ndarray, fit: HandleFit | None = None) -> np.ndarray:
    """``points`` [N, 3] turned about z so the handle points along +x (same units, origin kept)."""
    fit = fit or fit_handle(points)
    return np.asarray(points, np.float64) @ turn_about_z(-fit.azimuth).T


def handle_zone_count(observed_obj: np.ndarray, canonical_obj: np.ndarray, direction) -> int:
    """How many observed points fall where the handle is (``handle_zone_mask``'s count)."""
    return int(np.count_nonzero(handle_zone_mask(observed_obj, canonical_obj, direction)))


def handle_zone_mask(observed_obj: np.ndarray, canonical_obj: np.ndarray, direction,
                     max_ratio: float | None = None, observed_body: bool = False) -> np.ndarray:
    """[P] bool: which observed points fall where the handle is, both clouds in the category frame.

    Convention: ``observed_obj`` [P, 3] and ``canonical_obj`` [M, 3] in the same unit, category frame (z up, the
    handle along ``direction`` [3], a horizontal unit vector). The body axis and the per-height body radius come from
    the canonical shape (``fit_handle``'s circle fit, with the canonical points turned so ``direction`` is +x; the body
    radius of a height band is the 90th percentile radius of its points away from the handle); the handle zone is the
    part of space beyond ``HANDLE_ZONE_MARGIN`` × the body radius of the point's height band, within ±40° of the
    handle azimuth, inside the canonical shape's height range and (``max_ratio`` given) within ``max_ratio`` × the
    body radius. Points there cannot belong to the body: if the pose
    were turned about the axis, or the handle were hidden, the zone would be empty. ``observed_body``: the zone also
    starts beyond ``HANDLE_ZONE_MARGIN`` × the outer wall the camera sees in the band — the 75th percentile radius of
    the *observed* points away from the handle (≥ 3 of them; else over all bands), above the inner wall and bottom
    seen through the opening: where the predicted shape is narrower than the body seen (a body cut by an occluder),
    its own wall would otherwise read as a handle.
    """
    obs = np.asarray(observed_obj, np.float64)
    can = np.asarray(canonical_obj, np.float64)
    d = np.asarray(direction, np.float64).reshape(3)
    if obs.ndim != 2 or obs.shape[1] != 3 or can.ndim != 2 or can.shape[1] != 3 or len(can) < 50:
        raise InvalidPointsError(f"handle_zone_mask needs [P, 3] and [M ≥ 50, 3] clouds, got {obs.shape}, {can.shape}")
    turn = turn_about_z(-np.arctan2(d[1], d[0]))                                     # handle direction → +x
    obs, can = obs @ turn.T, can @ turn.T
    fit = fit_handle(can)
    edges = _height_bands(can[:, 2], 6)
    cap = np.inf if max_ratio is None else float(max_ratio)
    return _zone_mask(obs, can, edges, float(fit.centre[0]), float(fit.centre[1]), cap, bool(observed_body))


@njit(cache=True)
def _off_handle_radii(x, cx, cy, band, bands, stat, fallback):
    """[bands] per height band: the ``stat`` percentile radius about (``cx``, ``cy``) of the points ``x`` [K, 3]
    more than 40° away from +x (the handle), ``band`` [K] their band; a band with < 3 such points takes that
    percentile over all bands, or ``fallback`` when there are < 3 in all."""
    K = len(x)
    r, off = np.empty(K), np.empty(K, np.bool_)
    for i in range(K):
        vx, vy = x[i, 0] - cx, x[i, 1] - cy
        r[i] = np.sqrt(vx * vx + vy * vy)
        off[i] = np.degrees(abs(np.arctan2(vy, vx))) > 40.0
    whole = r[off]
    every = sorted_percentile(np.sort(whole), stat) if len(whole) >= 3 else fallback
    out = np.empty(bands)
    for k in range(bands):
        sel = r[off & (band == k)]
        out[k] = sorted_percentile(np.sort(sel), stat) if len(sel) >= 3 else every
    return out


@njit(cache=True)
def _zone_mask(obs, can, edges, cx, cy, cap, observed_body):
    """``handle_zone_mask`` of ``obs`` [P, 3] against ``can`` [M, 3], both turned so the handle lies along +x, with
    the canonical height band ``edges`` [B + 1], the body axis at (``cx``, ``cy``), the outer bound ``cap`` and the
    ``observed_body`` bound."""
    bands = len(edges) - 1
    band_c = np.minimum(np.maximum(np.searchsorted(edges, can[:, 2]) - 1, 0), bands - 1)   # [M]
    body = _off_handle_radii(can, cx, cy, band_c, bands, 90.0, np.nan)     # [B] canonical body radius per band
    band_o = np.minimum(np.maximum(np.searchsorted(edges, obs[:, 2]) - 1, 0), bands - 1)   # [P]
    inner = HANDLE_ZONE_MARGIN * body                                       # [B] where the zone starts
    if observed_body:
        seen = _off_handle_radii(obs, cx, cy, band_o, bands, 75.0, 0.0)    # [B] observed outer wall per band
        inner = np.maximum(inner, HANDLE_ZONE_MARGIN * seen)
    out = np.empty(len(obs), np.bool_)
    for i in range(len(obs)):
        b = band_o[i]
        vx, vy = obs[i, 0] - cx, obs[i, 1] - cy
        r = np.sqrt(vx * vx + vy * vy)
        az = np.degrees(abs(np.arctan2(vy, vx)))
        out[i] = edges[0] <= obs[i, 2] <= edges[-1] and inner[b] < r <= cap * body[b] and az < 40.0
    return out


def clustered_count(points: np.ndarray, member: np.ndarray, *, radius_factor: float = 2.5, neighbours: int = 3) -> int:
    """How many of the ``member`` points have ≥ ``neighbours`` other members within ``radius_factor`` × the cloud's
    median nearest-neighbour spacing: the members that lie on a surface patch rather than scattered (e.g. a handle's
    points against flying pixels at an occluder's edge).

    Convention: ``points`` [N, 3] any unit; ``member`` [N] bool.
    """
    p = np.ascontiguousarray(points, np.float64)
    m = np.asarray(member, bool)
    if p.ndim != 2 or p.shape[1] != 3 or m.shape != (len(p),):
        raise InvalidPointsError(f"clustered_count needs [N, 3] points and an [N] mask, got {p.shape}, {m.shape}")
    if len(p) < 2 or not m.any():
        return 0
    return int(_clustered_count(p, np.flatnonzero(m), float(radius_factor), int(neighbours)))


@njit(cache=True)
def _clustered_count(p, members, radius_factor, neighbours):
    """``clustered_count`` of the points ``p`` [N, 3] at indices ``members`` [Z] (brute force: N ≤ a few thousand)."""
    N = len(p)
    nn = np.empty(N)
    for i in range(N):                                                         # nearest-neighbour spacing
        best = np.inf
        for j in range(N):
            if j != i:
                best = min(best, (p[i, 0] - p[j, 0]) ** 2 + (p[i, 1] - p[j, 1]) ** 2 + (p[i, 2] - p[j, 2]) ** 2)
        nn[i] = np.sqrt(best)
    r2 = (radius_factor * np.median(nn)) ** 2
    count = 0
    for a in range(len(members)):
        i, close = members[a], 0
        for b in range(len(members)):
            j = members[b]
            if j != i and (p[i, 0] - p[j, 0]) ** 2 + (p[i, 1] - p[j, 1]) ** 2 + (p[i, 2] - p[j, 2]) ** 2 <= r2:
                close += 1
        count += close >= neighbours
    return count
