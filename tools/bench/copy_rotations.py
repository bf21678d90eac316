"""Accuracy of a partial model with other sets of rotated input copies: the shipped seeded rotations against sets
spread over the quotient SO(3) / I (the network is equivariant to the 60 icosahedral rotations, so a copy turned by
one of them sees what copy 0 sees) and against other random draws.

Usage: python tools/bench/copy_rotations.py --model sdk/models/chair-partial.onnx --category chair [--count 4]
    [--split test|train] [--sets seeded,spread:0,spread:1,random:102]

Sets: ``seeded`` (``equipose.runtime.copies.copy_rotations``), ``spread:S`` (the identity and K − 1 rotations placed by
a seeded random search to minimise the mean distance from a random rotation to the nearest rotation of the copies'
icosahedral cosets), ``random:S`` (the identity and K − 1 uniform rotations from seed S). ``--split train`` runs the
first 100 training shapes × 5 rendered views instead of the test set (to choose without the test set). Prints per set:
its spread (smallest distance between two copies' cosets, mean and 95th-percentile covering distance, degrees) and
rotation median (°), 5° accuracy and flip rate through the SDK (``stages`` ``{"copies": {"count": K}}``, no ICP-60).
"""
from __future__ import annotations

import argparse
import json

import numpy as np
from scipy.spatial.transform import Rotation

from equipose.core.icosahedral import ANCHORS
from equipose.runtime.copies import copy_rotations

PROBES = Rotation.random(1500, random_state=7).as_matrix()                     # [S, 3, 3] fixed covering probes


def coset_distances(Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """[len(R), K] degrees from each rotation of ``R`` [n, 3, 3] to the nearest rotation of each coset I·Q_k."""
    M = np.einsum("hij,kjl->khil", ANCHORS, Q)                                  # [K, 60, 3, 3]
    tr = np.einsum("khij,sij->skh", M, R).max(-1)                               # [n, K] best trace per coset
    return np.degrees(np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0)))


def spread(Q: np.ndarray) -> tuple:
    """(smallest coset-to-coset distance, mean and p95 covering distance over ``PROBES``), degrees."""
    pair = min(coset_distances(Q[i:i + 1], Q[j:j + 1])[0, 0] for i in range(len(Q)) for j in range(i + 1, len(Q)))
    cover = coset_distances(Q, PROBES).min(1)
    return float(pair), float(cover.mean()), float(np.percentile(cover, 95))


def spread_set(k: int, seed: int, restarts: int = 20, steps: int = 300) -> np.ndarray:
    """The identity and ``k`` − 1 rotations that minimise the mean covering distance (seeded random search)."""
    rng = np.random.default_rng(seed)
    best = None
    for _ in range(restarts):
        Q = np.concatenate([np.eye(3)[None], Rotation.random(k - 1, random_state=rng.integers(1 << 31)).as_matrix()])
        cost, step = spread(Q)[1], 0.3
        for i in range(steps):
            trial = Q.copy()
            j = rng.integers(1, k)
            trial[j] = Rotation.from_rotvec(rng.normal(size=3) * step).as_matrix() @ Q[j]
            c = coset_distances(trial, PROBES).min(1).mean()
            if c < cost:
                Q, cost = trial, c
            if i % 100 == 99:
                step *= 0.5
        if best is None or cost < best[0]:
            best = (cost, Q)
    return best[1]


def rotation_set(name: str, k: int) -> np.ndarray:
    kind, _, seed = name.partition(":")
    if kind == "seeded":
        return copy_rotations(k)
    if kind == "spread":
        return spread_set(k, int(seed))
    if kind == "random":
        return np.concatenate([np.eye(3)[None], Rotation.random(k - 1, random_state=int(seed)).as_matrix()])
    raise SystemExit(f"unknown set {name!r}: seeded, spread:S or random:S")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--category", required=True)
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--split", choices=("test", "train"), default="test")
    ap.add_argument("--sets", default="seeded,spread:0,spread:1,spread:2,random:102,random:103")
    ap.add_argument("--cache-dir")
    a = ap.parse_args(argv)
    import equipose.runtime.stages.copies as copies_stage
    import equipose.train.evaluation.evaluate as ev
    if a.split == "train":
        from equipose.train.data.datasets import RenderedPartial
        from equipose.train.data.render_cache import ensure_cache

        def training_views(root, category, mode, num_points, limit=None, cache_dir=None, views=5):
            return RenderedPartial(ensure_cache(root, category, "train", cache_dir=cache_dir, limit=100, views=5,
                                                progress=False), num_points, train=False)
        ev.test_dataset = training_views
    for name in a.sets.split(","):
        Q = rotation_set(name, a.count)
        copies_stage.copy_rotations = lambda k, Q=Q: Q[:k]                      # the stage builds its copies from it
        res = ev.evaluate(category=a.category, mode="partial", model_path=a.model, icp_templates=0,
                          stages={"copies": {"count": a.count}}, cache_dir=a.cache_dir, progress=False,
                          log=lambda *_: None)
        row = res["rows"][0]
        pair, cover, p95 = spread(Q)
        print(json.dumps({"set": name, "count": a.count, "split": a.split, "closest_cosets_deg": round(pair, 1),
                          "covering_mean_deg": round(cover, 2), "covering_p95_deg": round(p95, 2),
                          "median_deg": round(row["rot_median_deg"], 3), "acc_5deg": row["acc_5deg"],
                          "flip": row["flip_rate"]}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
