"""Re-export the shipped models with the current exporter (same weights, same metadata, new graph).

For every ``sdk/models/NAME.onnx`` the training checkpoint is found by its weights (the decoder's output bias must equal
one of the file's initializers), exported again, checked against the shipped file on random FPS-ordered inputs
(every output within ``--atol``, same best hypothesis), and written with the shipped file's metadata props verbatim;
its int8 sibling is quantised again from the new fp32 file and gets the old int8 file's props verbatim. The stored
metrics stay valid because the outputs agree to float rounding.

Usage: python tools/reexport_models.py [--runs runs] [--models sdk/models] [--only NAME ...] [--dry-run]
"""
from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile

import numpy as np


def _initializer_vectors(path) -> list:
    import onnx
    from onnx import numpy_helper
    m = onnx.load(str(path))
    return [numpy_helper.to_array(t) for t in m.graph.initializer if len(t.dims) == 1]


def _checkpoint_biases(runs: pathlib.Path) -> dict:
    """{checkpoint path: decoder output bias} for every checkpoint under ``runs``."""
    import torch
    out = {}
    for ck in sorted(runs.glob("*/*.pt")):
        try:
            state = torch.load(ck, map_location="cpu", weights_only=False)
        except Exception:
            continue
        sd = state.get("state_dict") if isinstance(state, dict) else None
        if isinstance(sd, dict) and "decoder.out.bias" in sd:
            out[ck] = sd["decoder.out.bias"].numpy()
    return out


def _find_checkpoint(model_path, biases: dict):
    vecs = _initializer_vectors(model_path)
    hits = [ck for ck, b in biases.items() if any(v.shape == b.shape and np.array_equal(v, b) for v in vecs)]
    calibrated = [h for h in hits if h.name == "calibrated.pt"]
    return (calibrated or hits or [None])[0], hits


def _inputs(n: int, batch: int = 4, seed: int = 0) -> np.ndarray:
    from equipose.geometry import farthest_point_order
    rng = np.random.default_rng(seed)
    xs = []
    for _ in range(batch):
        p = rng.standard_normal((4 * n, 3)) * np.array([0.3, 0.2, 0.1])
        xs.append(p[farthest_point_order(p, n)])
    return np.stack(xs).astype(np.float32)


def _run(path, x) -> list:
    import onnxruntime as ort
    s = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return s.run(None, {"points": x})


def _write_with_props(graph_file, props_file, out):
    """Write ``graph_file``'s graph with ``props_file``'s metadata props to ``out`` (atomically)."""
    import onnx
    from equipose.export.onnx_export import _write_atomic
    a, b = onnx.load(str(props_file)), onnx.load(str(graph_file))
    del b.metadata_props[:]
    for p in a.metadata_props:
        b.metadata_props.add(key=p.key, value=p.value)
    _write_atomic(b, pathlib.Path(out))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="runs")
    ap.add_argument("--models", default="sdk/models")
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--atol", type=float, default=1e-4)
    ap.add_argument("--dry-run", action="store_true")
    args = ap.parse_args(argv)

    from equipose.export.onnx_export import export_model
    from equipose.export.quantize import quantize_int8
    from equipose.train.checkpoint import model_from_checkpoint

    biases = _checkpoint_biases(pathlib.Path(args.runs))
    print(f"{len(biases)} checkpoints under {args.runs}")
    failed = 0
    for path in sorted(pathlib.Path(args.models).glob("*.onnx")):
        if path.name.endswith(".int8.onnx") or (args.only and path.stem not in args.only):
            continue
        ck, hits = _find_checkpoint(path, biases)
        if ck is None:
            print(f"{path.name}: no checkpoint with its weights — skipped"); failed += 1
            continue
        model, _ = model_from_checkpoint(str(ck))
        with tempfile.TemporaryDirectory() as tmp:
            new = pathlib.Path(tmp) / path.name
            export_model(model, new, category="x", scale=1.0)
            x = _inputs(model.num_points)
            old_out, new_out = _run(path, x), _run(new, x)
            err = max(float(np.abs(a - b).max()) for a, b in zip(old_out, new_out))
            same_best = bool(np.array_equal(old_out[3].argmin(1), new_out[3].argmin(1)))
            ok = err <= args.atol and same_best
            print(f"{path.name}: {ck} ({len(hits)} match) max |Δ| {err:.2e}, same best hypothesis {same_best}"
                  + ("" if ok else "  → NOT written"))
            if not ok:
                failed += 1
                continue
            if args.dry_run:
                continue
            _write_with_props(new, path, path)
            q = path.with_name(path.stem + ".int8.onnx")
            if q.exists():
                q_new = pathlib.Path(tmp) / q.name
                quantize_int8(str(path), str(q_new))
                old_q = _run(q, x)
                new_q = _run(q_new, x)
                qerr = max(float(np.abs(a - b).max()) for a, b in zip(old_q, new_q))
                _write_with_props(q_new, q, q)
                print(f"  {q.name}: re-quantised (max |Δ| to the old int8 file {qerr:.2e})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
