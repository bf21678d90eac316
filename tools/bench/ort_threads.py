"""onnxruntime inference time of an equipose model on 1 vs 2 intra-op threads, per batch size (the evidence behind
``PoseEstimator(adaptive_threads=True)``). Random FPS-ordered inputs, no pre/post-processing: the graph run alone
(a format-2 graph gets the neighbourhoods it takes, computed before the timing).

Usage: python tools/bench/ort_threads.py MODEL.onnx [MODEL2.onnx ...] [--batches 1 2 8] [--runs 200]
Prints median ms over ``--runs`` runs, three repeats per cell (each in the same process).
"""
import argparse
import time

import numpy as np
import onnxruntime as ort

from equipose.core.geometry import farthest_point_order
from equipose.runtime.session import GraphIO


def session(path, threads):
    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")      # as PoseEstimator
    return ort.InferenceSession(path, so, providers=["CPUExecutionProvider"])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 2, 8])
    ap.add_argument("--runs", type=int, default=200)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    for path in args.models:
        s1 = session(path, 1)
        n = s1.get_inputs()[0].shape[1]
        io = GraphIO(s1, dict(s1.get_modelmeta().custom_metadata_map), path)
        for b in args.batches:
            pts = [rng.standard_normal((4 * n, 3)) * np.array([0.3, 0.2, 0.1]) for _ in range(b)]
            feeds = io.feeds(np.stack([p[farthest_point_order(p, n)] for p in pts]).astype(np.float32))
            cells = []
            for threads in (1, 2):
                s = s1 if threads == 1 else session(path, 2)
                for _ in range(20):
                    s.run(None, feeds)
                reps = []
                for _ in range(3):
                    ts = []
                    for _ in range(args.runs):
                        t = time.perf_counter()
                        s.run(None, feeds)
                        ts.append(time.perf_counter() - t)
                    reps.append(np.median(ts) * 1e3)
                cells.append(" ".join(f"{r:.2f}" for r in reps))
            print(f"{path}  batch {b}:  1 thread {cells[0]} ms   2 threads {cells[1]} ms", flush=True)


if __name__ == "__main__":
    main()
