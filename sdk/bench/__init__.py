"""CPU latency benchmark of the SDK pipeline (``equipose bench``): a tool that measures the runtime, not part of it.

``harness`` (run each backend on the bundled frame, one subprocess per backend; the table and JSON) and ``backends``
(the registry of ways to run the network: onnxruntime fp32 / int8 here, torch-side ones registered from
``equipose.train.bench_backends`` when first asked for). Names load lazily, so ``python -m equipose.bench.harness``
(the per-backend worker) does not import the harness twice.
"""
from __future__ import annotations

_LAZY = {
    "run_benchmark": "equipose.bench.harness", "run_backend": "equipose.bench.harness",
    "format_table": "equipose.bench.harness", "percentiles": "equipose.bench.harness",
    "matmul_peak_gmacs": "equipose.bench.harness",
    "Backend": "equipose.bench.backends", "BACKENDS": "equipose.bench.backends", "PROVIDERS": "equipose.bench.backends",
    "register_backend": "equipose.bench.backends", "get_backend": "equipose.bench.backends",
}

__all__ = sorted(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'equipose.bench' has no attribute {name!r}")
