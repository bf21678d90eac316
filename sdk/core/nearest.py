"""Compiled exact nearest-neighbour search for numba kernels (the ICP loop of ``equipose.core.icp``).

Two methods behind one index, chosen by the size of the point set (``BRUTE_MAX_POINTS``; measured side by side
with ``python tools/bench/nn_backends.py``, figures in docs/benchmarks.md):

- brute force: float32 squared distances to every point (a loop the compiler vectorises), then the minimum of the
  keys ``distance bits << 32 | index`` (vectorised too; non-negative floats order as their bit patterns), so ties go
  to the smaller index;
- a k-d tree, balanced by construction: a node over the index range [lo, hi) splits at its middle position (the
  median along the axis of largest spread, by quickselect), and ranges of at most ``LEAF_SIZE`` points are leaves.
  Its shape depends only on the number of points, so the trees of several sets of equal size stack into one set of
  arrays. Queries start their bound at a guess (in ICP: the partner the point had in the previous iteration), which
  prunes nearly every node.

Kernels unpack an index once and branch to ``nearest_brute`` / ``nearest_tree`` per query themselves: unpacking a
tuple of arrays costs reference counting on every call, about as much as a brute-force query of 256 points itself,
and a dispatcher taking the index's arrays measured 1.5–2× slower in the ICP loop.

Convention: points [M, 3] float64, one unit and one frame; returned distances are squared Euclidean in that unit,
recomputed in float64 from the chosen pair.
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["BRUTE_MAX_POINTS", "LEAF_SIZE", "build_index", "make_scratch", "nearest_brute", "nearest_tree",
           "nearest_distances", "nearest_all"]

BRUTE_MAX_POINTS = 512
LEAF_SIZE = 8
LO, HI, AXIS, LEFT, RIGHT = range(5)         # columns of a tree's node table (AXIS −1: a leaf)


@njit(cache=True)
def _node_count(m: int) -> int:
    """Nodes of the tree over ``m`` points (leaves hold at most ``LEAF_SIZE``)."""
    count, stack = 0, [m]
    while stack:
        size = stack.pop()
        count += 1
        if size > LEAF_SIZE:
            stack.append(size // 2)
            stack.append(size - size // 2)
    return count


@njit(cache=True)
def _select(points, order, lo, hi, nth, axis):
    """Reorder ``order[lo..hi]`` (inclusive) so that position ``nth`` holds the point whose ``axis`` coordinate
    ranks there, with no larger coordinate before it and no smaller one after it (Hoare's quickselect)."""
    while lo < hi:
        pivot = points[order[(lo + hi) // 2], axis]
        i, j = lo, hi
        while i <= j:
            while points[order[i], axis] < pivot:
                i += 1
            while points[order[j], axis] > pivot:
                j -= 1
            if i <= j:
                order[i], order[j] = order[j], order[i]
                i += 1
                j -= 1
        if nth <= j:
            hi = j
        elif nth >= i:
            lo = i
        else:
            return


@njit(cache=True)
def _build_tree(points, order, nodes, split):
    """Fill one tree in place: ``order`` [M] (point index per sorted position), ``nodes`` [n, 5], ``split`` [n]."""
    stack = np.empty((64, 3), np.int64)                                         # (node, lo, hi)
    stack[0, 0], stack[0, 1], stack[0, 2] = 0, 0, len(order)
    top, used = 1, 1
    while top:
        top -= 1
        node, a, b = stack[top, 0], stack[top, 1], stack[top, 2]
        nodes[node, LO], nodes[node, HI] = a, b
        if b - a <= LEAF_SIZE:
            nodes[node, AXIS] = -1
            continue
        best, k = -1.0, 0
        for d in range(3):                                                      # axis of largest spread
            mn, mx = np.inf, -np.inf
            for p in range(a, b):
                v = points[order[p], d]
                mn, mx = min(mn, v), max(mx, v)
            if mx - mn > best:
                best, k = mx - mn, d
        mid = a + (b - a) // 2
        _select(points, order, a, b - 1, mid, k)                                # median to mid, smaller before it
        nodes[node, AXIS], split[node] = k, points[order[mid], k]
        nodes[node, LEFT], nodes[node, RIGHT] = used, used + 1
        stack[top, 0], stack[top, 1], stack[top, 2] = used, a, mid
        stack[top + 1, 0], stack[top + 1, 1], stack[top + 1, 2] = used + 1, mid, b
        top += 2
        used += 2


@njit(cache=True)
def build_index(P, brute_max: int = BRUTE_MAX_POINTS) -> tuple:
    """The index of ``P`` [T, M ≥ 1, 3] float64 (T sets of equal size) as arrays:

    (P, soa [T, 3, M] float32 centred per set, centre [T, 3], tree points [T, M, 3] in tree order,
    ids [T, 2, M] (original index of each tree position, and its inverse), nodes [T, n, 5] int64, split [T, n]).
    Sets of at most ``brute_max`` points get no tree (its arrays are empty) and are searched by brute force."""
    T, M = P.shape[0], P.shape[1]
    centre = np.zeros((T, 3))
    soa = np.empty((T, 3, M), np.float32)
    for k in range(T):
        for a in range(3):
            c = 0.0
            for m in range(M):
                c += P[k, m, a]
            centre[k, a] = c / M
            for m in range(M):
                soa[k, a, m] = P[k, m, a] - centre[k, a]
    Mt = M if M > brute_max else 0
    n = _node_count(Mt) if Mt else 0
    tpoints, ids = np.empty((T, Mt, 3)), np.empty((T, 2, Mt), np.int64)
    nodes, split = np.zeros((T, n, 5), np.int64), np.zeros((T, n))
    for k in range(T if Mt else 0):
        ids[k, 0] = np.arange(M)
        _build_tree(P[k], ids[k, 0], nodes[k], split[k])
        for p in range(M):
            ids[k, 1, ids[k, 0, p]] = p
            tpoints[k, p] = P[k, ids[k, 0, p]]
    return P, soa, centre, tpoints, ids, nodes, split


@njit(cache=True)
def make_scratch(size: int) -> tuple:
    """Work arrays for queries on sets of up to ``size`` points: (int64 [64], float64 [64], float32 [size] and
    its int32 view)."""
    dist = np.empty(max(size, 1), np.float32)
    return np.empty(64, np.int64), np.empty(64), dist, dist.view(np.int32)


@njit(cache=True, fastmath=True)
def nearest_brute(soa, centre, k, q, dist, bits) -> int:
    """Index of the point of set ``k`` (``soa``, ``centre`` of an index) nearest to ``q`` [3] float64; ``dist`` and
    ``bits``: scratch (``make_scratch``)."""
    qx = np.float32(q[0] - centre[k, 0])
    qy = np.float32(q[1] - centre[k, 1])
    qz = np.float32(q[2] - centre[k, 2])
    M = soa.shape[2]
    for m in range(M):
        dx, dy, dz = soa[k, 0, m] - qx, soa[k, 1, m] - qy, soa[k, 2, m] - qz
        dist[m] = dx * dx + dy * dy + dz * dz
    best = np.int64(0x7FFFFFFFFFFFFFFF)
    for m in range(M):
        key = (np.int64(bits[m]) << 32) | m
        best = key if key < best else best
    return best & 0xFFFFFFFF


@njit(cache=True)
def nearest_tree(tpoints, ids, nodes, split, k, q, guess, stack, bound) -> int:
    """Index of the point of tree ``k`` (``tpoints``, ``ids``, ``nodes``, ``split`` of an index) nearest to ``q``
    [3]. ``guess``: an index whose distance starts the bound (−1: none); ``stack``, ``bound``: scratch."""
    if guess >= 0:
        bp = ids[k, 1, guess]
        dx, dy, dz = tpoints[k, bp, 0] - q[0], tpoints[k, bp, 1] - q[1], tpoints[k, bp, 2] - q[2]
        best = dx * dx + dy * dy + dz * dz
    else:
        best, bp = np.inf, -1
    stack[0], bound[0] = 0, 0.0
    top = 1
    while top:
        top -= 1
        node = stack[top]
        if bound[top] > best:                                                   # the whole node lies farther
            continue
        ax = nodes[k, node, AXIS]
        while ax >= 0:                                                          # down to the leaf holding q,
            diff = q[ax] - split[k, node]                                       # the far sides kept for later
            near_left = diff < 0.0
            stack[top] = nodes[k, node, RIGHT] if near_left else nodes[k, node, LEFT]
            bound[top] = diff * diff
            top += 1
            node = nodes[k, node, LEFT] if near_left else nodes[k, node, RIGHT]
            ax = nodes[k, node, AXIS]
        for p in range(nodes[k, node, LO], nodes[k, node, HI]):
            dx, dy, dz = tpoints[k, p, 0] - q[0], tpoints[k, p, 1] - q[1], tpoints[k, p, 2] - q[2]
            d = dx * dx + dy * dy + dz * dz
            if d < best:
                best, bp = d, p
    return ids[k, 0, bp]


@njit(cache=True)
def nearest_all(index, queries, guess, out) -> None:
    """``out`` [Q] = index of the point of set 0 of ``index`` nearest to each of ``queries`` [Q, 3]; ``guess`` [Q]:
    a likely answer per query (e.g. the previous one in an iteration; −1: none), or [0] for none at all."""
    P, soa, centre, tpoints, ids, nodes, split = index
    stack, bound, dist, bits = make_scratch(P.shape[1])
    q = np.empty(3)                                                             # a row view per query would cost
    for i in range(len(queries)):                                               # reference counting
        q[0], q[1], q[2] = queries[i, 0], queries[i, 1], queries[i, 2]
        if tpoints.shape[1]:
            g = guess[i] if len(guess) else -1
            out[i] = nearest_tree(tpoints, ids, nodes, split, 0, q, g, stack, bound)
        else:
            out[i] = nearest_brute(soa, centre, 0, q, dist, bits)


@njit(cache=True)
def nearest_distances(points, queries, brute_max: int = BRUTE_MAX_POINTS):
    """[Q] float64 distance from each of ``queries`` [Q, 3] to its nearest point of ``points`` [M ≥ 1, 3] (both
    float64): ``NearestNeighbours(points).query(queries)[0]`` in one compiled call (the same search and pairs)."""
    index = build_index(points.reshape(1, points.shape[0], 3), brute_max)
    idx = np.empty(len(queries), np.int64)
    nearest_all(index, queries, np.zeros(0, np.int64), idx)
    out = np.empty(len(queries))
    for i in range(len(queries)):
        j = idx[i]
        dx, dy, dz = queries[i, 0] - points[j, 0], queries[i, 1] - points[j, 1], queries[i, 2] - points[j, 2]
        out[i] = np.sqrt(dx * dx + dy * dy + dz * dz)
    return out
