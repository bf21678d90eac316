"""CPU latency benchmark of the whole pipeline (crop → FPS ordering → inference → selection) per backend.

Convention:
    Input: one 640×480 depth frame (the bundled PCL mug sample, uint16 mm) and ``objects`` copies of its object box
    (objects per frame = model batch). Times are wall-clock milliseconds (``time.perf_counter``) after warm-up;
    "end-to-end" is one ``predict``-equivalent call for all objects of the frame, per object figures divide by it.
    Backends (``equipose.bench.backends``; each measured in a fresh subprocess, so ``peak_rss_mb`` is that
    backend's own peak resident memory): onnxruntime-fp32, onnxruntime-int8, and the torch-side torch and icp60
    (``equipose.train.bench_backends``, registered when first asked for).
    Threads: ``threads`` is every backend's budget (torch ``set_num_threads``); onnxruntime runs a single object of a
    light model on one of them (``PoseEstimator(adaptive_threads=True)``, the SDK default) unless asked not to.
    The "bound" is the model's analytic MACs divided by the measured single-MatMul peak (GMAC/s) of this CPU with the
    same thread count: the time a perfectly MatMul-bound implementation would need.
"""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
import time

import numpy as np

from equipose.bench.backends import BACKENDS, get_backend
__all__ = ["BACKENDS", "run_backend", "run_benchmark", "matmul_peak_gmacs", "format_table", "percentiles",
           "host_state"]
STAGES = ("crop", "fps", "inference", "selection")
BUSY_WARN = 0.1                 # other work on this share of the cores or more: the figures are not idle figures


def percentiles(ms: list) -> dict:
    """p50/p95/max of a list of milliseconds."""
    a = np.asarray(ms, np.float64)
    return {"p50_ms": float(np.percentile(a, 50)), "p95_ms": float(np.percentile(a, 95)), "max_ms": float(a.max())}


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0   # Linux: kilobytes


def _cpu_jiffies():
    """(busy, total) clock ticks of all CPUs since boot from /proc/stat, or None where it cannot be read."""
    try:
        with open("/proc/stat") as f:
            fields = [int(v) for v in f.readline().split()[1:9]]    # user nice system idle iowait irq softirq steal
    except (OSError, ValueError):
        return None
    total = sum(fields)
    return total - fields[3] - fields[4], total


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    import platform
    return platform.processor() or platform.machine()


def host_state(seconds: float = 0.3) -> dict:
    """{"cpu": model name, "cores": logical CPUs, "busy": share of all cores that other work kept busy during
    ``seconds`` while this process slept (0–1; None where /proc/stat cannot be read)}. Niced jobs count: they still
    take cycles and caches from the timed runs."""
    a = _cpu_jiffies()
    time.sleep(seconds)
    b = _cpu_jiffies()
    busy = None
    if a is not None and b is not None and b[1] > a[1]:
        busy = min(1.0, max(0.0, (b[0] - a[0]) / (b[1] - a[1])))
    return {"cpu": _cpu_model(), "cores": os.cpu_count() or 1, "busy": busy}


def _sample_frame():
    from equipose.samples import sample_objects, sample_path
    from equipose.sources import FolderSource
    frame = next(iter(FolderSource(sample_path())))
    return frame, sample_objects()[0]["box"]


def matmul_peak_gmacs(threads: int, size: int = 512, runs: int = 20) -> float:
    """Best-of-``runs`` GMAC/s of one [size×size]·[size×size] float32 MatMul in onnxruntime (``threads`` threads).

    Builds the one-node graph with ``onnx`` when available; otherwise measures numpy's matmul (noted by the caller).
    """
    a = np.random.default_rng(0).standard_normal((size, size)).astype(np.float32)
    try:
        from onnx import TensorProto, helper
        import onnxruntime as ort
        g = helper.make_graph([helper.make_node("MatMul", ["a", "b"], ["c"])], "mm",
                              [helper.make_tensor_value_info("a", TensorProto.FLOAT, [size, size]),
                               helper.make_tensor_value_info("b", TensorProto.FLOAT, [size, size])],
                              [helper.make_tensor_value_info("c", TensorProto.FLOAT, [size, size])])
        m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
        m.ir_version = 8
        so = ort.SessionOptions()
        so.intra_op_num_threads = threads
        s = ort.InferenceSession(m.SerializeToString(), so, providers=["CPUExecutionProvider"])
        fn = lambda: s.run(None, {"a": a, "b": a})  # noqa: E731
    except ImportError:
        fn = lambda: a @ a  # noqa: E731
    fn()
    best = min(_timed(fn) for _ in range(runs))
    return size ** 3 / best / 1e9 * 1e3


def _timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return (time.perf_counter() - t) * 1e3


# ----------------------------------------------------------------------------------------------------------------------
# One backend, in this process

def run_backend(backend: str, model_path: str, threads: int = 2, objects: int = 1, runs: int = 100,
                warmup: int = 5, checkpoint: str | None = None, refine="auto", adaptive_threads: bool = True,
                profile: str = "default", stages: dict | None = None) -> dict:
    """Measure one backend in this process. Returns a row dict (end-to-end and per-stage percentiles, fps, rss).

    ``threads`` is the budget of every backend; onnxruntime follows ``PoseEstimator(adaptive_threads=...)`` within it
    (the row's ``threads_used`` says what ran)."""
    from equipose.runtime.estimator import PoseEstimator

    spec = get_backend(backend)
    path = spec.model_file(model_path) if spec.model_file else model_path
    est = PoseEstimator(path, threads=threads, refine=refine, adaptive_threads=adaptive_threads, profile=profile,
                        stages=stages)
    frame, box = _sample_frame()
    boxes = [box] * objects
    note, parity = spec.setup(est, frame, box, threads=threads, checkpoint=checkpoint) if spec.setup else ("", None)

    def one_frame() -> dict:
        """One ``predict_batch`` call (the SDK path, with this backend as runner); stage times from its results."""
        t0 = time.perf_counter()
        results = est.predict_batch(frame.depth, frame.K, boxes=boxes, depth_unit=frame.depth_unit,
                                    image_size=frame.image_size)
        st = {"total": (time.perf_counter() - t0) * 1e3}
        for k in ("crop", "fps", "selection"):                                  # per object → per frame
            st[k] = sum(r.timings[k] for r in results)
        st["inference"] = results[0].timings["inference"]                       # one batched run per frame
        for r in results:                                                       # the pipeline's stages, per frame
            for name, ms in r.timings.get("stages", {}).items():
                st["stage:" + name] = st.get("stage:" + name, 0.0) + ms
        return st

    for _ in range(warmup):
        one_frame()
    samples = [one_frame() for _ in range(runs)]
    row = {"backend": backend, "model": os.path.basename(path), **percentiles([s["total"] for s in samples])}
    row["fps"] = 1e3 / row["p50_ms"] * objects
    row["per_object_p50_ms"] = row["p50_ms"] / objects
    row["peak_rss_mb"] = _peak_rss_mb()
    row["model_mb"] = os.path.getsize(path) / 2 ** 20 if spec.runs_model_file else None
    row["stages"] = {k: percentiles([s[k] for s in samples]) for k in STAGES}
    row["pipeline"] = {k[6:]: percentiles([s.get(k, 0.0) for s in samples])["p50_ms"]
                       for k in samples[0] if k.startswith("stage:")}             # p50 ms of each pipeline stage
    row["profile"] = profile
    row["stages_options"] = stages
    row["runs"], row["threads"], row["objects"], row["refine"] = runs, threads, objects, est.refine
    row["copies"] = est.copies
    row["threads_used"] = 1 if spec.runs_model_file and est.uses_single_thread(objects * est.copies) else threads
    if note:
        row["note"] = note
    if parity is not None:
        row["parity_max_abs"] = parity
    return row


# ----------------------------------------------------------------------------------------------------------------------
# Orchestration: one subprocess per backend

def _run_isolated(backend, model_path, threads, objects, runs, warmup, checkpoint, refine="auto",
                  adaptive_threads=True, profile="default", stages=None) -> dict:
    cmd = [sys.executable, "-m", "equipose.bench.harness", backend, model_path, str(threads), str(objects), str(runs),
           str(warmup), checkpoint or "", str(refine), "1" if adaptive_threads else "0", profile,
           json.dumps(stages)]
    env = dict(os.environ, OMP_NUM_THREADS=str(threads), DEPTHAI_LEVEL="error")
    p = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["(no output)"])[-1]
        return {"backend": backend, "error": last}
    return json.loads(p.stdout.strip().splitlines()[-1])


def run_benchmark(model_path: str, backends=BACKENDS, threads: int = 2, objects: int = 1, runs: int = 100,
                  warmup: int = 5, checkpoint: str | None = None, isolate: bool = True, refine="auto",
                  adaptive_threads: bool = True, profile: str = "default", stages: dict | None = None) -> dict:
    """All requested backends on the same frame; returns ``{"model", "threads", "points", "objects", "rows",
    "ratios", ...}``; ``ratios[backend]`` = its end-to-end and inference-stage p50 ÷ onnxruntime-fp32's."""
    from equipose.runtime.estimator import PoseEstimator
    from equipose.core.presets import ModelConfig, total_macs

    host = host_state()                                                         # before anything of ours runs
    est = PoseEstimator(model_path, threads=threads)
    cfg = ModelConfig.from_dict(est.metadata["model_config"])
    macs = total_macs(cfg, partial=bool(est.metadata["partial"]))
    peak = matmul_peak_gmacs(threads)
    rows = []
    for b in backends:
        row = (_run_isolated if isolate else lambda *a: run_backend(*a))(b, str(model_path), threads, objects, runs,
                                                                         warmup, checkpoint, refine,
                                                                         adaptive_threads, profile, stages)
        rows.append(row)
        print(f"  measured {b}: " + (f"p50 {row['p50_ms']:.1f} ms" if "p50_ms" in row else row["error"]),
              file=sys.stderr, flush=True)
    ref = next((r for r in rows if r.get("backend") == "onnxruntime-fp32" and "p50_ms" in r), None)
    ratios = {r["backend"]: {"end_to_end": r["p50_ms"] / ref["p50_ms"],
                             "inference": r["stages"]["inference"]["p50_ms"] / ref["stages"]["inference"]["p50_ms"]}
              for r in rows if ref and "p50_ms" in r}
    return {"model": str(model_path), "preset": cfg.name, "threads": threads, "points": est.num_points,
            "refine": rows[0].get("refine") if rows else None, "copies": rows[0].get("copies") if rows else None,
            "adaptive_threads": adaptive_threads, "profile": profile, "stages_options": stages,
            "objects": objects, "macs": macs, "matmul_peak_gmacs": peak, "bound_ms": macs * objects / peak / 1e6,
            "host": host, "rows": rows, "ratios": ratios}


def format_table(result: dict) -> str:
    """A text table of ``run_benchmark``'s result, with speed ratios against onnxruntime-fp32."""
    rows = result["rows"]
    lines = [f"model {result['model']} (preset {result['preset']}, N={result['points']}, "
             f"{result['macs'] / 1e9:.3f} GMAC/object), {result['threads']} thread(s), {result['objects']} object(s)/frame"
             f", profile {result.get('profile', 'default')}"
             + (f", stages {json.dumps(result['stages_options'])}" if result.get("stages_options") else "")
             + f", ICP re-scoring of {result.get('refine') or 0} hypotheses (selection stage)"
             + (f", {result['copies']} rotated input copies per object" if (result.get("copies") or 1) > 1 else ""),
             f"MatMul peak {result['matmul_peak_gmacs']:.1f} GMAC/s → bound {result['bound_ms']:.2f} ms/frame",
             *_host_lines(result.get("host")),
             f"{'backend':<18} {'p50 ms':>8} {'bound':>6} {'p95 ms':>8} {'max ms':>8} {'FPS':>8} {'RSS MB':>8} "
             f"{'size MB':>8} {'× fp32':>7}  {'crop':>6} {'fps':>6} {'infer':>7} {'× fp32':>7} {'select':>6} "
             f"{'threads':>7}"]
    for r in rows:
        if "error" in r:
            lines.append(f"{r['backend']:<18} unavailable: {r['error']}")
            continue
        ratios = result["ratios"].get(r["backend"], {})
        ratio, inf_ratio = ratios.get("end_to_end", float("nan")), ratios.get("inference", float("nan"))
        s = r["stages"]
        size = f"{r['model_mb']:.2f}" if r.get("model_mb") else "-"
        bound = f"{result['bound_ms']:.2f}" if r["backend"] != "icp60" else "-"    # the network's MatMul bound
        lines.append(f"{r['backend']:<18} {r['p50_ms']:>8.2f} {bound:>6} {r['p95_ms']:>8.2f} {r['max_ms']:>8.2f} {r['fps']:>8.1f} "
                     f"{r['peak_rss_mb']:>8.0f} {size:>8} {ratio:>7.2f}  {s['crop']['p50_ms']:>6.2f} "
                     f"{s['fps']['p50_ms']:>6.2f} {s['inference']['p50_ms']:>7.2f} {inf_ratio:>7.2f} "
                     f"{s['selection']['p50_ms']:>6.2f} {r.get('threads_used', r['threads']):>7}"
                     + (f"   ({r['note']})" if r.get("note") else ""))
    first = next((r for r in rows if r.get("pipeline")), None)
    if first:
        lines.append("selection by stage (p50 ms, " + first["backend"] + "): " +
                     " · ".join(f"{k} {v:.2f}" for k, v in first["pipeline"].items() if v >= 0.01))
    return "\n".join(lines)


def _host_lines(host) -> list:
    """The table's host line, and a warning where other work was running."""
    if not host:
        return []
    busy = host.get("busy")
    line = f"host {host['cpu']}, {host['cores']} logical CPUs" + (
        f", other work {100 * busy:.0f} % of them just before the runs" if busy is not None else "")
    if busy is not None and busy >= BUSY_WARN:
        return [line, "warning: other work was running on this host: these are not idle figures (stop other jobs, "
                      "including niced ones, to measure)"]
    return [line]


def _worker_main(argv):
    backend, model, threads, objects, runs, warmup, ckpt, refine, adaptive, profile, stages = argv
    row = run_backend(backend, model, int(threads), int(objects), int(runs), int(warmup), ckpt or None,
                      "auto" if refine == "auto" else int(refine), adaptive_threads=adaptive == "1",
                      profile=profile, stages=json.loads(stages))
    sys.stdout.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    _worker_main(sys.argv[1:])
