"""``equipose bench``: CPU latency of the whole pipeline per backend, one table with ratios (see ``equipose.bench``)."""
from __future__ import annotations

import json
import pathlib
import sys
import tempfile

from equipose.commands import stage_options
from equipose.core.errors import ConfigError

COMPARE = {"torch": "torch", "icp": "icp60", "int8": "onnxruntime-int8"}


def add_arguments(p):
    p.add_argument("--model", default=None, help="equipose .onnx model or a shipped model's name (default: demo model)")
    p.add_argument("--threads", type=int, default=2,
                   help="CPU thread budget of every backend (default 2); onnxruntime runs a single object of a light "
                        "model on one of them, as the SDK does, unless --fixed-threads")
    p.add_argument("--fixed-threads", dest="fixed_threads", action="store_true",
                   help="onnxruntime uses all --threads even for a single object (PoseEstimator(adaptive_threads=False))")
    p.add_argument("--points", type=int, default=None,
                   help="model input points N; if it differs from the model's, a random-weight variant of the same "
                        "preset at N is exported and measured (needs the train extra)")
    p.add_argument("--batch", type=int, default=1, help="objects per frame (one onnxruntime run of this batch)")
    p.add_argument("--compare", default="torch,icp,int8",
                   help="extra backends next to onnxruntime-fp32: any of torch,icp,int8 ('' for none)")
    p.add_argument("--runs", type=int, default=100, help="timed runs per backend (≥ 100 for reported figures)")
    p.add_argument("--warmup", type=int, default=5)
    p.add_argument("--checkpoint", default=None, help="torch backend: load these weights (default: export seed)")
    p.add_argument("--sweep", action="store_true",
                   help="latency vs N (256, 512, 1024, 2048), threads (1, 2) and objects per frame (1..8), fp32 only")
    p.add_argument("--json", dest="json_path", default=None, help="write the results as JSON to this file")
    p.add_argument("--profile", default="default", choices=["fast", "default", "accurate"],
                   help="the pipeline's speed / accuracy point (PoseEstimator(profile=...)), every backend")
    p.add_argument("--refine", default="auto",
                   help="ICP re-scoring of K hypotheses in every backend (default 'auto': the model file's setting)")
    p.add_argument("--stages", default=None,
                   help="stage options over the profile's, as JSON (PoseEstimator(stages=...)), every backend, e.g. "
                        "'{\"view\": {\"k\": 3}}'")


def _resolve_model(name):
    if name is None:
        from equipose.models import demo_model_path
        return str(demo_model_path())
    path = pathlib.Path(name)
    if path.is_file():
        return str(path)
    try:
        from equipose.models import resolve_model
        return str(resolve_model(name))
    except (ImportError, AttributeError):
        raise ConfigError(f"model {name!r} is neither a file nor a shipped model name") from None


def _variant_at(model_path: str, n: int, tmp: pathlib.Path) -> str:
    """A random-weight export of the model's preset with ``n`` input points (same widths/radii)."""
    from equipose.runtime.estimator import PoseEstimator
    from equipose.core.presets import ModelConfig
    est = PoseEstimator(model_path)
    if est.num_points == n:
        return model_path
    try:
        from equipose.export.onnx_export import export_random_model
    except ImportError:
        raise ConfigError(f"--points {n} differs from the model's N={est.num_points}; measuring another N needs the "
                          "train extra (pip install 'equipose[train]')") from None
    cfg = ModelConfig.from_dict(est.metadata["model_config"])
    cfg = cfg.replace(name=f"{cfg.name}@{n}", num_points=n)
    out = tmp / f"{cfg.name.replace('@', '_n')}.onnx"
    export_random_model(cfg, out, partial=est.metadata["partial"], category=est.category, scale=est.scale,
                        verify=False)
    return str(out)


def run(args) -> int:
    from equipose.bench.harness import format_table, run_benchmark
    if args.threads < 1 or args.batch < 1 or args.runs < 1:
        raise ConfigError("--threads, --batch and --runs must be ≥ 1")
    model = _resolve_model(args.model)
    extra = [c.strip() for c in args.compare.split(",") if c.strip()]
    bad = [c for c in extra if c not in COMPARE]
    if bad:
        raise ConfigError(f"--compare takes torch, icp, int8; got {', '.join(bad)}")
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="equipose-bench-"))
    if args.points:
        model = _variant_at(model, args.points, tmp)
    refine = args.refine
    if refine != "auto":
        try:
            refine = int(refine)
        except ValueError:
            raise ConfigError(f"--refine takes 'auto' or an integer ≥ 0, got {args.refine!r}") from None
        if refine < 0:
            raise ConfigError(f"--refine takes 'auto' or an integer ≥ 0, got {refine}")
    if args.sweep:
        return _sweep(model, args, tmp, refine)
    backends = ["onnxruntime-fp32"] + [COMPARE[c] for c in extra]
    result = run_benchmark(model, backends, threads=args.threads, objects=args.batch, runs=args.runs,
                           warmup=args.warmup, checkpoint=args.checkpoint, refine=refine,
                           adaptive_threads=not args.fixed_threads, profile=args.profile,
                           stages=stage_options(args.stages))
    print(format_table(result))
    if args.json_path:
        pathlib.Path(args.json_path).write_text(json.dumps(result, indent=1))
    return 0


def _sweep(model, args, tmp, refine="auto") -> int:
    from equipose.bench.harness import run_backend
    runs = min(args.runs, 30)
    out = {"model": model, "runs": runs, "refine": refine, "points": [], "threads": [], "objects": []}
    print(f"sweep (onnxruntime-fp32, {runs} runs each, end-to-end p50 ms, ICP re-scoring: {refine}; random-weight "
          "variants at other N)")
    for n in (256, 512, 1024, 2048):
        try:
            m = _variant_at(model, n, tmp)
        except ConfigError as e:
            print(f"  N={n}: skipped ({e})", file=sys.stderr)
            continue
        r = run_backend("onnxruntime-fp32", m, args.threads, 1, runs, 3, refine=refine,
                        adaptive_threads=not args.fixed_threads)
        out["points"].append({"n": n, "p50_ms": r["p50_ms"], "p95_ms": r["p95_ms"]})
        print(f"  N={n:5d}  threads={r['threads_used']}  objects=1  p50 {r['p50_ms']:8.2f}  p95 {r['p95_ms']:8.2f}", flush=True)
    for t in (1, 2):                                                            # exactly t threads
        r = run_backend("onnxruntime-fp32", model, t, 1, runs, 3, refine=refine, adaptive_threads=False)
        out["threads"].append({"threads": t, "p50_ms": r["p50_ms"], "p95_ms": r["p95_ms"]})
        print(f"  model N  threads={t}  objects=1  p50 {r['p50_ms']:8.2f}  p95 {r['p95_ms']:8.2f}", flush=True)
    for b in range(1, 9):
        r = run_backend("onnxruntime-fp32", model, args.threads, b, runs, 3, refine=refine,
                        adaptive_threads=not args.fixed_threads)
        out["objects"].append({"objects": b, "p50_ms": r["p50_ms"], "per_object_ms": r["p50_ms"] / b})
        print(f"  model N  threads={args.threads}  objects={b}  p50 {r['p50_ms']:8.2f}  per object "
              f"{r['p50_ms'] / b:8.2f}", flush=True)
    if args.json_path:
        pathlib.Path(args.json_path).write_text(json.dumps(out, indent=1))
    return 0
