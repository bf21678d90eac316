"""Reliability benchmark: random-input fuzz, a long soak over changing frames, and threads sharing one estimator.

Prints figures for docs/reliability.md; exits 1 if anything but the package's own errors escaped, a pose was not a
finite rotation, memory grew by more than ``--max-rss-growth-mb`` or threads disagreed with the sequential results.

Usage:
    python tools/bench/reliability.py fuzz --seconds 300
    python tools/bench/reliability.py soak --frames 10000
    python tools/bench/reliability.py threads --threads 4 --frames 200
    python tools/bench/reliability.py all
"""
from __future__ import annotations

import argparse
import collections
import sys
import threading
import time

import numpy as np

from equipose import PoseEstimator, errors
from equipose.runtime.result import FrameError
from equipose.samples import sample_path
from equipose.sources import FolderSource

MODEL = "cup-tabletop.int8"


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def sample_frame():
    f = next(iter(FolderSource(sample_path("table_mug"))))
    return f.depth, f.K, f.image_size


def moving_frames(n: int, seed: int = 0):
    """The bundled mug frame panned by up to ±12 px and given ±3 mm noise: every frame differs."""
    depth, K, size = sample_frame()
    rng = np.random.default_rng(seed)
    for i in range(n):
        d = np.roll(depth, int(12 * np.sin(i / 15.0)), axis=1).astype(np.int32)
        valid = d > 0
        d[valid] += rng.integers(-3, 4, size=int(valid.sum()))
        yield d.astype(np.uint16), K, size


def proper(r) -> bool:
    R = r.rotation
    return bool(np.all(np.isfinite(R)) and np.all(np.isfinite(r.translation))
                and np.allclose(R @ R.T, np.eye(3), atol=1e-5) and np.linalg.det(R) > 0)


# ---------------------------------------------------------------------------------------------------------------------
def _garbage_call(est, rng, depth0, K0):
    """One random call of a public entry point on damaged input."""
    kind = rng.integers(7)
    if kind == 0:                                                               # random dtype/shape frames
        dt = rng.choice([np.uint16, np.float32, np.float64, np.int32, np.uint8, np.bool_])
        shape = tuple(rng.integers(0, 80, size=rng.integers(1, 4)))
        d = (rng.normal(size=shape) * 10 ** rng.uniform(-3, 5)).astype(dt)
        return est.predict(d, K0, box=tuple(rng.uniform(-50, 100, 4)))
    if kind == 1:                                                               # the real frame, damaged regions/K
        K = K0 * rng.choice([1, 1e-9, -1, np.nan, 1e6]) if rng.random() < 0.5 else K0
        box = tuple(rng.uniform(-100, 700, 4))
        return est.predict(depth0, K, box=box, depth_unit=rng.choice(["mm", "m", 0.001, 2.0]))
    if kind == 2:                                                               # point clouds of every sort
        n = int(rng.integers(0, 400))
        pts = rng.normal(size=(n, int(rng.integers(1, 5)))) * 10 ** rng.uniform(-13, 4)
        if rng.random() < 0.3:
            pts[rng.integers(max(n, 1)) % max(n, 1):] = np.nan
        return est.predict_points(pts.astype(rng.choice([np.float64, np.float32, np.int64])))
    if kind == 3:                                                               # masks of the wrong kind
        m = rng.choice([np.nan, 0, 1, 2]) * np.ones(depth0.shape[:2]) if rng.random() < 0.7 \
            else np.ones((5, 5))
        return est.predict(depth0, K0, mask=m)
    if kind == 4:                                                               # crop options
        opts = {k: v for k, v in {"max_points": int(rng.integers(-2, 5000)), "outlier_k": int(rng.integers(-1, 20)),
                                  "outlier_std": float(rng.uniform(-1, 4)), "min_depth": float(rng.uniform(-1, 2)),
                                  "max_depth": float(rng.uniform(-1, 12))}.items() if rng.random() < 0.5}
        return est.predict(depth0, K0, box=(200, 120, 200, 200), **opts)
    if kind == 5:                                                               # batches mixing good and bad regions
        boxes = [tuple(rng.uniform(-50, 600, 4)) for _ in range(int(rng.integers(0, 4)))]
        return est.predict_batch(depth0, K0, boxes=boxes, return_errors=bool(rng.random() < 0.5))
    d = depth0.copy()                                                           # auto crop on damaged frames
    d[rng.random(d.shape) < rng.random()] = 0
    return est.predict_auto(d, K0)


def run_fuzz(seconds: float, seed: int = 0) -> bool:
    est = PoseEstimator(MODEL, threads=1)
    depth0, K0, _ = sample_frame()
    rng = np.random.default_rng(seed)
    counts, escaped = collections.Counter(), []
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end:
        try:
            out = _garbage_call(est, rng, depth0, K0)
            for r in out if isinstance(out, list) else [out]:
                if isinstance(r, FrameError):
                    counts["per-object error"] += 1
                elif proper(r):
                    counts["pose"] += 1
                else:
                    escaped.append("improper pose")
        except errors.EquiposeError as e:
            counts[type(e).__name__] += 1
        except Exception as e:  # anything else is a defect
            escaped.append(f"{type(e).__name__}: {e}")
    calls = sum(counts.values())
    print(f"fuzz: {calls} calls in {seconds:.0f} s, escaped (not equipose errors): {len(escaped)}")
    for k, v in counts.most_common():
        print(f"  {k:24s} {v}")
    for e in escaped[:10]:
        print("  ESCAPED", e)
    return not escaped


def run_soak(frames: int, max_growth_mb: float) -> bool:
    est = PoseEstimator(MODEL)
    lat, bad, rss = [], 0, []
    for i, (d, K, size) in enumerate(moving_frames(frames)):
        t0 = time.perf_counter()
        out = est.predict_auto(d, K, image_size=size, return_errors=True)
        lat.append((time.perf_counter() - t0) * 1e3)
        bad += sum(1 for r in out if isinstance(r, FrameError) or not proper(r)) + (len(out) == 0)
        if i == 100 or (i + 1) % max(1, frames // 4) == 0:                      # after warm-up, then each quarter
            rss.append(rss_mb())
    lat = np.array(lat)
    tenth = max(1, frames // 10)
    first, last = np.median(lat[:tenth]), np.median(lat[-tenth:])
    growth = rss[-1] - rss[0]
    print(f"soak: {frames} frames, {bad} without a proper pose; latency median {np.median(lat):.2f} ms, p99 "
          f"{np.percentile(lat, 99):.2f} ms; first/last tenth median {first:.2f}/{last:.2f} ms; RSS after frame 100 "
          f"and each quarter: {' → '.join(f'{r:.1f}' for r in rss)} MB ({growth:+.1f} MB; last half "
          f"{rss[-1] - rss[len(rss) // 2]:+.1f} MB)")
    return bad == 0 and rss[-1] - rss[len(rss) // 2] <= max_growth_mb / 2


def run_threads(n_threads: int, frames: int) -> bool:
    est = PoseEstimator(MODEL)
    inputs = list(moving_frames(frames, seed=1))
    t0 = time.perf_counter()
    ref = [est.predict_auto(d, K, image_size=s) for d, K, s in inputs]
    seq_s = time.perf_counter() - t0
    results = [[None] * frames for _ in range(n_threads)]
    failures = []

    def work(k):
        try:
            for i, (d, K, s) in enumerate(inputs):
                results[k][i] = est.predict_auto(d, K, image_size=s)
        except Exception as e:  # recorded and reported
            failures.append(repr(e))

    threads = [threading.Thread(target=work, args=(k,)) for k in range(n_threads)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    par_s = time.perf_counter() - t0
    diff = 0.0
    for k in range(n_threads):
        for a, b in zip(ref, results[k]):
            if len(a) != len(b):
                diff = float("inf")
                continue
            for ra, rb in zip(a, b):
                diff = max(diff, float(np.abs(ra.rotation - rb.rotation).max()),
                           float(np.abs(ra.translation - rb.translation).max()))
    print(f"threads: {n_threads} threads × {frames} frames on one estimator: {len(failures)} failures, max |Δ| vs "
          f"sequential {diff:.2e}; {frames / seq_s:.1f} frames/s sequential, {n_threads * frames / par_s:.1f} frames/s "
          "together")
    return not failures and diff == 0.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["fuzz", "soak", "threads", "all"])
    ap.add_argument("--seconds", type=float, default=300.0, help="fuzz duration")
    ap.add_argument("--frames", type=int, default=None, help="soak frames (10000) / frames per thread (200)")
    ap.add_argument("--threads", type=int, default=4)
    ap.add_argument("--max-rss-growth-mb", type=float, default=20.0)
    a = ap.parse_args(argv)
    ok = True
    if a.what in ("fuzz", "all"):
        ok &= run_fuzz(a.seconds)
    if a.what in ("soak", "all"):
        ok &= run_soak(a.frames or 10000, a.max_rss_growth_mb)
    if a.what in ("threads", "all"):
        ok &= run_threads(a.threads, a.frames or 200)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
