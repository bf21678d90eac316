"""The object a box prompt is drawn around: depth clusters, connected surfaces on the pixel lattice, their growth into
objects, and the choice among them by evidence instead of nearness.

Convention: ``z`` [P] metres, ``rows``, ``cols`` [P] int frame pixels of the box's points, ``points`` [P, 3] metres in
the camera frame, ``box`` (x0, y0, x1, y1) pixel bounds, ``focal`` pixels. Labels are [P] int, 0 = nearest. The
decisions run compiled (numba); the public functions are their typed entry points.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from equipose.core.order_statistics import selected_percentile, sorted_median

__all__ = ["nearest_depth_cluster", "depth_clusters", "surface_segments", "box_object_cluster", "occluded_fraction",
           "continues_beyond_box", "CUT_PENALTY"]

CUT_PENALTY = 0.3       # score factor of a candidate whose surface runs on past the box's sides (an occluder)
CUT_SHARE = 0.5         # ... where this share of its points along the left, right and top sides continue outside
SEED_SHARE = 0.5        # a surface seeds a candidate object from this share of ``min_fraction`` on (a bowl's front
                        # wall seen over its rim can hold 6–10 % of the box's points)


def nearest_depth_cluster(z: np.ndarray, gap_m: float = 0.03, rel_gap: float = 0.03,
                          min_fraction: float = 0.1) -> np.ndarray:
    """Keep the nearest depth cluster that is big enough (background rejection inside a box).

    Convention: ``z`` [P] metres. Sorted depths are split wherever consecutive values differ by more than
    max(``gap_m``, ``rel_gap`` · z); the nearest cluster holding at least ``min_fraction`` of the points wins.
    Returns [P] bool.
    """
    P = len(z)
    if P == 0:
        return np.zeros(0, dtype=bool)
    labels = depth_clusters(z, gap_m, rel_gap)                                  # [P], nearest = 0
    counts = np.bincount(labels)                                                # [C]
    big = np.nonzero(counts >= max(1, min_fraction * P))[0]
    chosen = int(big[0]) if len(big) else int(np.argmax(counts))
    return labels == chosen


def depth_clusters(z: np.ndarray, gap_m: float = 0.03, rel_gap: float = 0.03) -> np.ndarray:
    """[P] cluster label of each depth in ``z`` [P] metres, 0 = nearest: sorted depths split wherever consecutive
    values differ by more than max(``gap_m``, ``rel_gap`` · z)."""
    return _depth_labels(np.ascontiguousarray(z, np.float64), float(gap_m), float(rel_gap))


@njit(cache=True)
def _depth_labels(z, gap_m, rel_gap):
    order = np.argsort(z, kind="mergesort")                                     # stable
    labels = np.empty(len(z), np.int64)
    label = 0
    for k in range(len(z)):
        if k > 0 and z[order[k]] - z[order[k - 1]] > max(gap_m, rel_gap * z[order[k - 1]]):
            label += 1
        labels[order[k]] = label
    return labels


def surface_segments(z: np.ndarray, rows: np.ndarray, cols: np.ndarray, step: int, focal: float,
                     min_jump: float = 0.012, slant: float = 4.0) -> tuple:
    """Connected surfaces of an organized crop.

    Convention: ``z`` [P] metres of points on a regular pixel lattice of pitch ``step`` (``rows``, ``cols`` [P] frame
    pixels); ``focal`` pixels. Lattice neighbours (4-connected) belong to one surface when their depths differ by less
    than max(``min_jump`` · max(1, z²), ``slant`` · step · z / focal): the sensor's noise grows with z², and a surface
    slanted away from the camera steps by up to ``slant`` lattice spacings per pixel. An occluder standing in front
    of the object is its own surface even where its depths overlap the object's, which a split of the depth values
    alone cannot tell apart.
    Returns (labels [P] int, 0 = the nearest surface by mean depth, ties in the lattice's row-major order; cut
    (i [L], j [L]): the neighbour pairs split by a depth jump, vertical pairs then horizontal ones, each row-major,
    ``z[j] − z[i]`` the jump).
    """
    rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    gi, gj = (rows - rows.min()) // step, (cols - cols.min()) // step          # [P] lattice indices
    return _surface_labels(np.ascontiguousarray(z, np.float64), gi, gj, float(step), float(focal), float(min_jump),
                           float(slant))


@njit(cache=True)
def _root(parent, a):
    while parent[a] != a:
        parent[a] = parent[parent[a]]                                           # path halving
        a = parent[a]
    return a


@njit(cache=True)
def _tolerance(za, zb, spacing, focal, min_jump, slant):
    """Largest depth step (m) between two points of one surface ``spacing`` pixels apart (``surface_segments``)."""
    zm = 0.5 * (za + zb)
    return max(min_jump * max(1.0, zm * zm), slant * spacing * zm / focal)


@njit(cache=True)
def _surface_labels(z, gi, gj, step, focal, min_jump, slant):
    P = len(z)
    gh, gw = gi.max() + 1, gj.max() + 1
    grid = np.full((gh, gw), -1, np.int64)                                      # [gh, gw] point at each cell
    for p in range(P):
        grid[gi[p], gj[p]] = p
    parent = np.arange(P)
    cut_i, cut_j = np.empty(2 * P, np.int64), np.empty(2 * P, np.int64)
    n_cut = 0
    for vertical in (True, False):                                              # lower, then right neighbours
        for r in range(gh - 1 if vertical else gh):
            for c in range(gw if vertical else gw - 1):
                a = grid[r, c]
                b = grid[r + 1, c] if vertical else grid[r, c + 1]
                if a < 0 or b < 0:
                    continue
                if abs(z[a] - z[b]) < _tolerance(z[a], z[b], step, focal, min_jump, slant):
                    ra, rb = _root(parent, a), _root(parent, b)
                    if ra != rb:
                        parent[max(ra, rb)] = min(ra, rb)
                else:
                    cut_i[n_cut], cut_j[n_cut] = a, b
                    n_cut += 1
    ident = np.full(P, -1, np.int64)                                            # component id, row-major first seen
    n = 0
    for r in range(gh):
        for c in range(gw):
            if grid[r, c] >= 0:
                root = _root(parent, grid[r, c])
                if ident[root] < 0:
                    ident[root] = n
                    n += 1
    comp = np.empty(P, np.int64)
    total, count = np.zeros(n), np.zeros(n)
    for p in range(P):                                                          # a point shares its cell's surface
        comp[p] = ident[_root(parent, grid[gi[p], gj[p]])]
        total[comp[p]] += z[p]
        count[comp[p]] += 1.0
    rank = np.empty(n, np.int64)
    rank[np.argsort(total / count, kind="mergesort")] = np.arange(n)           # by mean depth, nearest = 0
    labels = np.empty(P, np.int64)
    for p in range(P):
        labels[p] = rank[comp[p]]
    return labels, (cut_i[:n_cut].copy(), cut_j[:n_cut].copy())


def continues_beyond_box(depth: np.ndarray, z: np.ndarray, rows: np.ndarray, cols: np.ndarray, box, step: int,
                         focal: float, min_jump: float = 0.012, slant: float = 4.0) -> np.ndarray:
    """[P] bool: the points on the box's left, right or top side whose surface runs on outside the box.

    Convention: ``depth`` [H, W] metres (0 = invalid), the whole frame; ``z`` [P] metres, ``rows``, ``cols`` [P] frame
    pixels of the box's points on a lattice of pitch ``step``; ``box`` (x0, y0, x1, y1), x1 and y1 exclusive;
    ``focal`` pixels. A point within one lattice pitch of a side continues when the frame's depth 2 pixels beyond
    that side differs from its own by less than ``surface_segments``' neighbour tolerance over that distance. A
    detector's box is drawn around its object, so the object ends at the box; an occluder standing in front runs on
    past it. The bottom side is left out: an object and its occluder both meet the table there.
    """
    x0, y0, x1, y1 = (int(b) for b in box)
    return _beyond(np.ascontiguousarray(depth, np.float32), np.ascontiguousarray(z, np.float64),
                   np.ascontiguousarray(rows, np.int64), np.ascontiguousarray(cols, np.int64), x0, y0, x1, y1,
                   max(int(step), 1), float(focal), float(min_jump), float(slant))


@njit(cache=True)
def _beyond(depth, z, rows, cols, x0, y0, x1, y1, step, focal, min_jump, slant):
    """``continues_beyond_box`` on typed arrays: [P] bool."""
    H, W = depth.shape
    out = np.zeros(len(z), np.bool_)
    for p in range(len(z)):
        r, c = rows[p], cols[p]
        for side in range(3):                                                   # left, right, top
            if side == 0 and c - x0 < step and x0 >= 2:
                rr, cc = r, x0 - 2
            elif side == 1 and x1 - 1 - c < step and x1 + 1 < W:
                rr, cc = r, x1 + 1
            elif side == 2 and r - y0 < step and y0 >= 2:
                rr, cc = y0 - 2, c
            else:
                continue
            d = depth[rr, cc]
            if d <= 0.0:
                continue
            gap = abs(rr - r) + abs(cc - c)                                     # pixels
            if abs(d - z[p]) < _tolerance(d, z[p], gap, focal, min_jump, slant):
                out[p] = True
    return out


@njit(cache=True)
def _cut_labels(labels, n_labels, rows, cols, box, step, beyond):
    """[n_labels] bool: the surfaces or clusters that run on past the box (``CUT_SHARE`` of their points on the left,
    right and top sides continue outside, at least 3 of them)."""
    x0, y0, x1 = box[0], box[1], box[2]
    edge, cont = np.zeros(n_labels), np.zeros(n_labels)
    for p in range(len(labels)):
        if cols[p] - x0 < step or x1 - 1 - cols[p] < step or rows[p] - y0 < step:
            edge[labels[p]] += 1.0
            cont[labels[p]] += beyond[p]
    return (cont >= 3.0) & (cont >= CUT_SHARE * edge)


def box_object_cluster(z: np.ndarray, rows: np.ndarray, cols: np.ndarray, box, min_fraction: float = 0.1,
                       border: float = 0.08, labels: np.ndarray | None = None, cut: tuple | None = None,
                       points: np.ndarray | None = None, focal: float | None = None,
                       beyond: np.ndarray | None = None, step: int = 1, nearer: np.ndarray | None = None) -> tuple:
    """The object a box prompt is drawn around, chosen by evidence instead of nearness.

    Convention: ``z`` [P] metres, ``rows``, ``cols`` [P] frame pixels of the box's points; ``box`` (x0, y0, x1, y1)
    pixel bounds. Candidates: with ``labels`` [P] (0 = nearest), ``cut`` (``surface_segments``), ``points`` [P, 3]
    metres and ``focal`` pixels, each surface holding at least ``SEED_SHARE`` × ``min_fraction`` of the points, grown
    by the surfaces it hides in part while the union fits in a sphere of half the box's diagonal at the seed's depth,
    or at the union's depth where it is no deeper than the box is wide (``_grow``: the box bounds the object's size);
    otherwise the split of the depth values (``depth_clusters``).

    Each candidate scores share × fit × exp(−2 d²), d the offset of its pixel centroid from the box centre in half-box
    units (a detector's box is centred on its object). Depth clusters: fit = 1 − the candidate's share of the box's
    border band (the outer ``border`` of each side), as background surrounds the object along the border. Surfaces:
    fit = the share of the box's width × height its pixels span (the box spans its object, not what stands in front
    of it), × 0.3 when it still borders from in front a large surface that does not reach all four sides of the box
    (it hides another object: an occluder; background reaches every side). With ``beyond`` [P] bool
    (``continues_beyond_box``; ``step`` the lattice pitch), a candidate whose seed surface or cluster runs on past the
    box's sides scores × ``CUT_PENALTY``: the box ends at its object. ``nearer`` [P] bool (surfaces only): the points
    of the depth clusters in front of the one the surfaces were cut from, passed with it so that a surface of the
    object split off by a depth gap (a bowl's front wall before its inside) can join it.
    Returns ([P] bool, info {"clusters", "front_points", "occluded_fraction": front points / (those + the object's)}):
    in front = the depth clusters nearer than the chosen one, or the surfaces bordering the grown object from in front
    and the ``nearer`` points left out.
    """
    P = len(z)
    if P == 0:
        return np.zeros(0, bool), {"clusters": 0, "front_points": 0, "occluded_fraction": 0.0}
    z = np.ascontiguousarray(z, np.float64)
    rows, cols = np.ascontiguousarray(rows, np.int64), np.ascontiguousarray(cols, np.int64)
    bounds = np.array([float(b) for b in box])                                  # [4] x0, y0, x1, y1
    beyond = np.zeros(P, np.bool_) if beyond is None else np.ascontiguousarray(beyond, np.bool_)   # [P]
    if labels is not None and cut is not None and points is not None and focal:
        nearer = np.zeros(P, np.bool_) if nearer is None else np.ascontiguousarray(nearer, np.bool_)   # [P]
        keep, n_big, front = _choose_surface(z, rows, cols, bounds, np.ascontiguousarray(labels, np.int64),
                                             np.ascontiguousarray(cut[0], np.int64),
                                             np.ascontiguousarray(cut[1], np.int64),
                                             np.ascontiguousarray(points, np.float64), float(focal),
                                             float(min_fraction), float(border), beyond, int(step), nearer)
    else:
        labels = depth_clusters(z) if labels is None else np.ascontiguousarray(labels, np.int64)
        keep, n_big, front = _choose_cluster(rows, cols, bounds, labels, float(min_fraction), float(border), beyond,
                                             int(step))
    return keep, {"clusters": int(n_big), "front_points": int(front),
                  "occluded_fraction": occluded_fraction(front, keep)}


def occluded_fraction(front: int, kept: np.ndarray) -> float:
    """Share of an object's view taken by ``front`` points in front of it: front / (front + its ``kept`` [P] bool)."""
    return round(front / max(front + int(np.count_nonzero(kept)), 1), 4)


@njit(cache=True)
def _big_labels(labels, min_fraction, base):
    """(counts [C], the labels holding ≥ ``min_fraction`` of ``base`` points, else the largest one)."""
    counts = np.bincount(labels)
    big = np.nonzero(counts >= max(1.0, min_fraction * base))[0]
    if len(big) == 0:
        big = np.array([np.argmax(counts)])
    return counts, big


@njit(cache=True)
def _box_frame(box):
    """(cx, cy, hw, hh): the box's centre and half sizes (≥ 1) in pixels."""
    x0, y0, x1, y1 = box[0], box[1], box[2], box[3]
    return (x0 + x1) / 2.0, (y0 + y1) / 2.0, max((x1 - x0) / 2.0, 1.0), max((y1 - y0) / 2.0, 1.0)


@njit(cache=True)
def _sides(rows, cols, box, border, hw, hh):
    """[4, P] bool: each point within the outer ``border`` band of the box's left, right, top, bottom side."""
    x0, y0, x1, y1 = box[0], box[1], box[2], box[3]
    out = np.empty((4, len(rows)), np.bool_)
    for p in range(len(rows)):
        out[0, p] = cols[p] - x0 < 2 * border * hw
        out[1, p] = x1 - 1 - cols[p] < 2 * border * hw
        out[2, p] = rows[p] - y0 < 2 * border * hh
        out[3, p] = y1 - 1 - rows[p] < 2 * border * hh
    return out


@njit(cache=True)
def _centre_offset2(members, rows, cols, cx, cy, hw, hh):
    """(members' count, squared offset of their pixel centroid from the box centre in half-box units)."""
    n, sr, sc = 0, 0.0, 0.0
    for p in range(len(members)):
        if members[p]:
            n += 1
            sr += rows[p]
            sc += cols[p]
    return n, ((sc / n - cx) / hw) ** 2 + ((sr / n - cy) / hh) ** 2


@njit(cache=True)
def _choose_cluster(rows, cols, box, labels, min_fraction, border, beyond, step):
    """Depth-cluster candidates: (keep [P] bool, number of candidates, points in nearer clusters)."""
    P = len(labels)
    counts, big = _big_labels(labels, min_fraction, P)
    cut = _cut_labels(labels, len(counts), rows, cols, box, step, beyond)       # [C] runs on past the box
    cx, cy, hw, hh = _box_frame(box)
    sides = _sides(rows, cols, box, border, hw, hh)
    band = sides[0] | sides[1] | sides[2] | sides[3]                           # [P] in the border band
    n_band = max(band.sum(), 1)
    best, best_score = 0, -np.inf
    for k in range(len(big)):
        members = labels == big[k]
        n, offset2 = _centre_offset2(members, rows, cols, cx, cy, hw, hh)
        fit = (1.0 - (band & members).sum() / n_band) * (CUT_PENALTY if cut[big[k]] else 1.0)
        score = n / P * fit * np.exp(-2.0 * offset2)
        if score > best_score:
            best, best_score = k, score
    return labels == big[best], len(big), counts[: big[best]].sum()


@njit(cache=True)
def _radius(points, members):
    """Robust radius (m) of the ``members`` [P] bool of ``points`` [P, 3]: the 95th percentile distance from the centre
    of their 2–98 % box (a partial view's median lies off the object's centre, towards the camera)."""
    sel = points[members]                                                       # [M, 3]
    centre = np.empty(3)
    for a in range(3):
        s = np.ascontiguousarray(sel[:, a])
        centre[a] = 0.5 * (selected_percentile(s, 2.0) + selected_percentile(s, 98.0))
    d = np.empty(len(sel))
    for m in range(len(sel)):
        dx, dy, dz = sel[m, 0] - centre[0], sel[m, 1] - centre[1], sel[m, 2] - centre[2]
        d[m] = np.sqrt(dx * dx + dy * dy + dz * dz)
    return selected_percentile(d, 95.0)


@njit(cache=True)
def _boundary_jumps(labels, n_labels, z, cut_i, cut_j, inside):
    """[n_labels] median depth jump (m) from the ``inside`` points [P] bool to each surface outside that borders them
    over their cut neighbour pairs (> 0: it lies behind, < 0: in front); NaN where a surface does not border."""
    diffs = np.empty(len(cut_i))
    owner = np.empty(len(cut_i), np.int64)
    m = 0
    for k in range(len(cut_i)):
        i, j = cut_i[k], cut_j[k]
        if inside[i] == inside[j]:
            continue
        if not inside[i]:                                                       # orient the pair inside → outside
            i, j = j, i
        diffs[m], owner[m] = z[j] - z[i], labels[j]
        m += 1
    out = np.full(n_labels, np.nan)
    order = np.argsort(owner[:m], kind="mergesort")                             # the pairs grouped by surface
    a = 0
    while a < m:
        seg, b = owner[order[a]], a
        while b < m and owner[order[b]] == seg:
            b += 1
        out[seg] = sorted_median(np.sort(diffs[order[a:b]]))
        a = b
    return out


@njit(cache=True)
def _depth_extent(z, members):
    """Depth extent (m) of the ``members`` [P] bool: the span of their 2–98 % depths."""
    sel = z[members]
    return selected_percentile(sel, 98.0) - selected_percentile(sel, 2.0)


@njit(cache=True)
def _grow(seed, labels, n_labels, z, cut_i, cut_j, points, diag_per_m, width_per_m):
    """The object grown from surface ``seed``: the surfaces bordering it from behind join (smallest depth jump first)
    while the union fits the box — a cup's front wall and its inside beyond the rim are two surfaces of one object,
    while what stands in front of an object never joins it, and the wall behind makes the union too large.

    A union fits when its radius stays within the box's half diagonal in metres at the seed's median depth
    (``diag_per_m`` × that depth), or within it at the union's own median depth while the union is no deeper than the
    box is wide there (``width_per_m`` × that depth). The second test lets a seed nearer than the rest of its object
    (a bowl's front wall before its inside) grow; a gap to an object behind an occluder makes that union deeper than
    wide. Returns (members [P] bool,
    [n_labels] median jump of each bordering surface left out, NaN elsewhere; < 0 = in front)."""
    keep = labels == seed
    depth = sorted_median(np.sort(z[keep]))                                     # the object's median depth (m)
    max_radius = diag_per_m * depth                                             # the box's half diagonal at the seed
    for _ in range(32):                                                         # rounds of growth
        jumps = _boundary_jumps(labels, n_labels, z, cut_i, cut_j, keep)
        grown = False
        for seg in np.argsort(np.where(np.isnan(jumps), np.inf, jumps), kind="mergesort"):  # nearest in depth first
            jump = jumps[seg]
            if not (0.0 < jump <= 2.0 * diag_per_m * depth):                    # only what it hides in part
                continue
            union = keep | (labels == seg)
            radius = _radius(points, union)
            fits = radius <= max_radius
            if not fits:
                at = sorted_median(np.sort(z[union]))                           # the union's depth (m)
                fits = radius <= diag_per_m * at and _depth_extent(z, union) <= width_per_m * at
            if fits:
                keep, grown = union, True
                depth = sorted_median(np.sort(z[keep]))
        if not grown:
            return keep, jumps
    return keep, _boundary_jumps(labels, n_labels, z, cut_i, cut_j, keep)


@njit(cache=True)
def _choose_surface(z, rows, cols, box, labels, cut_i, cut_j, points, focal, min_fraction, border, beyond, step,
                    nearer):
    """Grown-surface candidates: (keep [P] bool, number of candidates, points in front: of the surfaces bordering it
    from in front, and the ``nearer`` [P] points left out that are not among those). A surface of the ``nearer``
    clusters seeds a candidate only where it grows into at least half of the cluster behind (a bowl's front wall into
    its inside); alone it is what stands in front."""
    P = len(z)
    base = P - np.count_nonzero(nearer)                                         # the shares refer to the cluster cut
    counts, big = _big_labels(labels, SEED_SHARE * min_fraction, base)
    n_labels = len(counts)
    in_front = np.zeros(n_labels, np.bool_)                                     # a surface of the nearer clusters
    for p in range(P):
        if nearer[p]:
            in_front[labels[p]] = True
    runs_on = _cut_labels(labels, n_labels, rows, cols, box, step, beyond)     # [n_labels] runs on past the box
    cx, cy, hw, hh = _box_frame(box)
    sides = _sides(rows, cols, box, border, hw, hh)
    enclosing = np.ones(n_labels, np.bool_)                                     # reaches every side of the box
    for s in range(4):
        reach = np.zeros(n_labels, np.bool_)
        for p in range(P):
            if sides[s, p]:
                reach[labels[p]] = True
        enclosing &= reach
    half_diag_px = 0.5 * math.hypot(box[2] - box[0], box[3] - box[1]) + step   # + a lattice pitch: the points'
                                                                             # extent is known to ± one pitch
    best_score = -np.inf
    best_keep, best_jumps = labels == big[0], np.full(n_labels, np.nan)
    if in_front[big[0]]:                                    # no candidate at all: the cluster cut, never what's in front
        best_keep = ~nearer
    candidates = 0
    for k in range(len(big)):
        seg = big[k]
        keep, jumps = _grow(seg, labels, n_labels, z, cut_i, cut_j, points, half_diag_px / focal, 2.0 * hw / focal)
        if in_front[seg] and np.count_nonzero(keep & ~nearer) < 0.5 * base:
            continue                                        # seeded in front: only as a part of the cluster behind
        candidates += 1
        n, offset2 = _centre_offset2(keep, rows, cols, cx, cy, hw, hh)
        c_lo, c_hi, r_lo, r_hi = cols.max(), cols.min(), rows.max(), rows.min()
        for p in range(P):
            if keep[p]:
                c_lo, c_hi = min(c_lo, cols[p]), max(c_hi, cols[p])
                r_lo, r_hi = min(r_lo, rows[p]), max(r_hi, rows[p])
        span = (c_hi - c_lo + 1) / (2 * hw) * (r_hi - r_lo + 1) / (2 * hh)
        hides = False                                       # a large surface behind it, not background all round
        for other in range(n_labels):
            if jumps[other] > 0 and counts[other] >= min_fraction * base and not enclosing[other]:
                hides = True
        fit = min(span, 1.0) * (0.3 if hides else 1.0) * (CUT_PENALTY if runs_on[seg] else 1.0)
        score = n / P * fit * np.exp(-2.0 * offset2)
        if score > best_score:
            best_score, best_keep, best_jumps = score, keep, jumps
    front = 0
    for other in range(n_labels):
        if best_jumps[other] < 0.0:
            front += counts[other]
    for p in range(P):
        if nearer[p] and not best_keep[p] and not best_jumps[labels[p]] < 0.0:
            front += 1
    return best_keep, candidates, front
