"""Exact rewrites of an exported equipose graph that onnxruntime's own optimiser does not make.

``drop_normalised_biases``: a layer's bias that an InstanceNormalization cancels. Every convolution of the backbone
adds a per-channel bias and then normalises each channel over its points and rotations (``layers.SeparableSO3Block``):
the normalisation subtracts the channel's mean, bias included, so the bias has no effect on any output. In the graph
it costs one broadcast Add per convolution (11 in ``edge-q``) over a 16–64-float inner dimension, a slow case of
onnxruntime's CPU kernels. What dropping them changes and saves: docs/benchmarks.md, v0.29.

Convention: functions take and return ``onnx.ModelProto`` (changed in place); ``rewrite_model_file`` checks the
rewritten file against the original on random inputs in onnxruntime and keeps every metadata entry.
"""
from __future__ import annotations

import collections
import json
import pathlib

import numpy as np

from equipose.core.errors import ModelFormatError
from equipose.models.model_io import read_model_file, write_model_file

__all__ = ["drop_normalised_biases", "rewrite_model", "rewrite_model_file", "max_output_difference"]

_LAYOUT_OPS = ("Reshape", "Transpose")          # ops that move values without mixing channels' sums
_MAX_HOPS = 6
FP32_ATOL = 1e-4                                # outputs of a rewritten fp32 graph (model units)
INT8_ATOL = 0.1                                 # int8: activations are re-quantised per call, a rounding can flip


def _consumers(graph) -> dict:
    users = collections.defaultdict(list)
    for node in graph.node:
        for name in node.input:
            users[name].append(node)
    return users


def _normalisation_reached(add, users, outputs):
    """The InstanceNormalization node that the Add's result reaches through layout ops alone, each value on the way
    read by that one op (and none a graph output); None if it reaches anything else first."""
    cur = add
    for _ in range(_MAX_HOPS):
        nxt = users.get(cur.output[0], [])
        if len(nxt) != 1 or cur.output[0] in outputs:
            return None
        cur = nxt[0]
        if cur.op_type == "InstanceNormalization":
            return cur
        if cur.op_type not in _LAYOUT_OPS:
            return None
    return None


def drop_normalised_biases(proto) -> dict:
    """Remove each Add of a constant 1-D bias whose result goes, through Reshape/Transpose only, into an
    InstanceNormalization whose scale has as many channels as the bias. Returns {bias initializer name: the
    initializer of the MatMul whose result the bias was added to ("" when none)}; ``rewrite_model`` keeps it in the
    metadata entry ``dropped_biases``, so ``checkpoint_from_onnx`` can still find each layer's weight.

    The normalisation subtracts each channel's mean, so a per-channel constant added before it changes no output.
    The channel match is checked on the sizes; ``rewrite_model_file`` also checks the outputs numerically."""
    from onnx import numpy_helper
    graph = proto.graph
    inits = {t.name: t for t in graph.initializer}
    users = _consumers(graph)
    outputs = {o.name for o in graph.output}
    producers = {o: n for n in graph.node for o in n.output}
    removed = {}
    for node in list(graph.node):
        if node.op_type != "Add" or len(node.input) != 2:
            continue
        bias_name = next((n for n in node.input if n in inits and len(inits[n].dims) == 1), None)
        norm = None if bias_name is None else _normalisation_reached(node, users, outputs)
        if norm is None:
            continue
        scale = inits.get(norm.input[1])
        if scale is None or numpy_helper.to_array(scale).size != int(inits[bias_name].dims[0]):
            continue
        data = next(n for n in node.input if n != bias_name)
        for user in users[node.output[0]]:
            for i, name in enumerate(user.input):
                if name == node.output[0]:
                    user.input[i] = data
        graph.node.remove(node)
        mm = producers.get(data)                                             # x @ W: W a 2-D initializer
        w = mm.input[1] if mm is not None and mm.op_type == "MatMul" else ""
        removed[bias_name] = w if w in inits and len(inits[w].dims) == 2 else ""
    used = {name for n in graph.node for name in n.input}
    for t in [t for t in graph.initializer if t.name not in used]:
        graph.initializer.remove(t)
    return removed


def rewrite_model(proto) -> dict:
    """Every rewrite of this module on ``proto`` (in place, metadata entry ``dropped_biases`` merged); returns
    {rewrite: what it removed}."""
    dropped = drop_normalised_biases(proto)
    if dropped:
        entry = next((p for p in proto.metadata_props if p.key == "dropped_biases"), None)
        if entry is None:
            entry = proto.metadata_props.add(key="dropped_biases", value="{}")
        entry.value = json.dumps({**json.loads(entry.value), **dropped}, sort_keys=True)
    return {"drop_normalised_biases": dropped}


def max_output_difference(before, after, batch: int = 2, seed: int = 0) -> float:
    """Largest absolute difference between the outputs of two graphs (``ModelProto``) of one equipose model on the
    same random input (points in model units and their neighbourhoods, as the runtime feeds them)."""
    import onnxruntime as ort
    from equipose.runtime.session import GraphIO
    meta = {p.key: p.value for p in before.metadata_props}
    if "model_config" not in meta or "num_points" not in meta:
        raise ModelFormatError("the graph has no equipose metadata (model_config, num_points); not an equipose model")
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    so.log_severity_level = 3
    sessions = [ort.InferenceSession(p.SerializeToString(), so, providers=["CPUExecutionProvider"])
                for p in (before, after)]
    x = (np.random.default_rng(seed).normal(size=(batch, int(meta["num_points"]), 3)) * 0.3).astype(np.float32)
    feeds = GraphIO(sessions[0], meta).feeds(x)                                 # points + neighbourhoods
    outs = [s.run(None, feeds) for s in sessions]
    return max(float(np.max(np.abs(a - b))) for a, b in zip(*outs))


def rewrite_model_file(path, out=None, atol: float | None = None) -> dict:
    """Rewrite an exported model file (fp32 or int8) and write it to ``out`` (default: in place), metadata kept.

    Checks the rewritten graph against the original on random inputs: the largest output difference must stay
    within ``atol`` (default ``FP32_ATOL``, ``INT8_ATOL`` for an int8 file), else ``ModelFormatError`` and nothing is
    written. Returns {"removed": {rewrite: what it removed}, "max_abs_diff": float}."""
    import onnx
    path = pathlib.Path(path)
    out = path if out is None else pathlib.Path(out)
    original = read_model_file(path)
    rewritten = onnx.ModelProto()
    rewritten.CopyFrom(original)
    removed = rewrite_model(rewritten)
    diff = max_output_difference(original, rewritten) if any(removed.values()) else 0.0
    int8 = {p.key: p.value for p in original.metadata_props}.get("precision") == "int8"
    limit = (INT8_ATOL if int8 else FP32_ATOL) if atol is None else float(atol)
    if not diff <= limit:
        raise ModelFormatError(f"{path.name}: the rewritten graph's outputs differ by {diff:.3g} (> {limit:g}) from "
                               "the original's; the file was left as it was")
    onnx.checker.check_model(rewritten, full_check=True)
    write_model_file(rewritten, out)
    return {"removed": removed, "max_abs_diff": diff}


def main(argv=None) -> int:
    """``python -m equipose.export.graph_rewrite FILE...``: rewrite model files in place; one line per file."""
    import argparse
    ap = argparse.ArgumentParser(prog="python -m equipose.export.graph_rewrite", description=main.__doc__)
    ap.add_argument("files", nargs="+", help="exported .onnx files (fp32 or int8)")
    args = ap.parse_args(argv)
    for f in args.files:
        res = rewrite_model_file(f)
        counts = ", ".join(f"{k} {len(v)}" for k, v in res["removed"].items())
        print(f"{f}: removed {counts}; max output difference {res['max_abs_diff']:.2g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
