"""Nearest-neighbour backends side by side on the SDK's ICP sizes: the measurement behind ``equipose.core.nearest``
(compiled brute force up to ``BRUTE_MAX_POINTS`` reference points, its compiled k-d tree above).

Usage: python tools/bench/nn_backends.py [--runs R] [--json FILE]
Each row: one query batch (J ICP starts × N observed points) against M reference points, median ms of R runs,
build excluded and included. Backends: the compiled brute force and k-d tree (each forced), scipy's cKDTree, and
pykdtree / small_gicp's KdTree where installed (``pip install pykdtree small_gicp``). Queries here start cold (the
ICP loop also warm-starts its tree queries from the previous partner).
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from equipose.core.neighbours import NearestNeighbours

SIZES = [(1, 256, 256), (5, 256, 256), (5, 128, 256), (12, 128, 256), (5, 256, 919), (1, 1024, 919),
         (5, 256, 1449), (1, 1024, 1024)]          # (starts J, observed N, reference M) as the pipeline's stages use


def _median_ms(fn, runs: int) -> float:
    fn()
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append((time.perf_counter() - t) * 1e3)
    return float(np.median(times))


def backends() -> dict:
    """{name: build(reference [M, 3]) → query(q [Q, 3]) callable} for every backend importable here."""
    out = {"brute": lambda P: NearestNeighbours(P, brute_max=len(P)).nearest_indices,
           "tree": lambda P: NearestNeighbours(P, brute_max=0).nearest_indices,
           "cKDTree": lambda P: NearestNeighbours(P, "kdtree").nearest_indices}
    try:
        from pykdtree.kdtree import KDTree
        out["pykdtree"] = lambda P: (lambda q, t=KDTree(P): t.query(q, k=1)[1])
    except ImportError:
        pass
    try:
        import small_gicp
        out["small_gicp"] = lambda P: (lambda q, t=small_gicp.KdTree(P): t.batch_nearest_neighbor_search(q)[0])
    except ImportError:
        pass
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--json", help="write the rows here")
    a = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    rows = []
    found = backends()
    print(f"{'J×N vs M':>16s} " + " ".join(f"{n:>22s}" for n in found) + "   (query ms / with build ms)")
    for J, N, M in SIZES:
        P = rng.standard_normal((M, 3)) * [1.0, 0.6, 0.4]
        q = rng.standard_normal((J * N, 3)) * [1.0, 0.6, 0.4]
        ref = NearestNeighbours(P, "kdtree").nearest_indices(q)
        row = {"starts": J, "observed": N, "reference": M}
        for name, build in found.items():
            query = build(P)
            agree = float(np.mean(np.asarray(query(q)).reshape(-1) == ref))
            row[name] = {"query_ms": _median_ms(lambda: query(q), a.runs),
                         "with_build_ms": _median_ms(lambda: build(P)(q), a.runs), "agree": agree}
        rows.append(row)
        print(f"{J:>3d}×{N:<4d} vs {M:<5d} " + " ".join(
            f"{row[n]['query_ms']:9.3f} / {row[n]['with_build_ms']:7.3f}{'' if row[n]['agree'] > 0.999 else '!'}"
            .rjust(22) for n in found))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
