"""Exact rewrites of an exported equipose graph that onnxruntime's own optimiser does not make.

``kernel_weights_as_inputs``: the kernel weights of every point convolution and the feature rows it gathers become
graph inputs that the runtime computes (``equipose.core.kernel_weights``; format 3, quotient presets). In the graph
they cost about 75 small nodes per run (offsets, squared norms, a concatenation, a transpose and a MatMul per layer,
and the batch offsets of the row indices), each one an onnxruntime kernel launch.

``class_weights_as_inputs``: the same cut one step later (format 4): the graph's inputs are the kernel weights
already summed per kernel class, in the layout of the MatMul that reads them, so each layer's constant [60, 13] class
MatMul and the reshapes, transpose and sum after it leave the graph (``equipose.core.kernel_weights.class_inputs``).

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

__all__ = ["drop_normalised_biases", "kernel_weights_as_inputs", "class_weights_as_inputs", "extract_graph",
           "rewrite_model", "rewrite_model_file", "max_output_difference"]

_LAYOUT_OPS = ("Reshape", "Transpose")          # ops that move values without mixing channels' sums
_CLASS_CHAIN_OPS = ("ReduceSum", "Reshape", "Transpose")   # what follows a class MatMul up to its feature MatMul
_MAX_HOPS = 6
FP32_ATOL = 1e-4                                # outputs of a rewritten fp32 graph (model units)
CLASS_LAYERS = (0,)                             # layers fed class weights by default (docs/benchmarks.md, v0.53)
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


_KERNEL_AUG_ATOL = 1e-6                          # a hat MatMul's [13, 5] constant against the layer's kernel_aug


def _hat_products(graph, inits: dict, users: dict) -> list:
    """The kernel-correlation MatMuls in graph order: ``MatMul([13, 5] constant, offsets)`` read by one Relu."""
    found = []
    for node in graph.node:
        if node.op_type != "MatMul" or node.input[0] not in inits or tuple(inits[node.input[0]].dims) != (13, 5):
            continue
        relu = users.get(node.output[0], [])
        if len(relu) == 1 and relu[0].op_type == "Relu":
            found.append((node, relu[0]))
    return found


def _layer_of_rows(rows: str, users: dict, hat_layer: dict, hops: int = 12):
    """The layer whose kernel-correlation MatMul a row-index tensor reaches first (breadth-first over consumers)."""
    frontier, seen = [rows], {rows}
    for _ in range(hops):
        nxt = []
        for name in frontier:
            for node in users.get(name, []):
                if node.name in hat_layer:
                    return hat_layer[node.name]
                for out in node.output:
                    if out not in seen:
                        seen.add(out)
                        nxt.append(out)
        frontier = nxt
    return None


def kernel_weights_as_inputs(proto) -> dict:
    """Cut a format-2 quotient graph at its kernel weights and feature-row indices, which become the inputs
    ``kernel_weights_<l>`` / ``neighbour_rows_<l>`` (``equipose.core.kernel_weights``); the neighbourhood inputs
    and every node that only fed the cut values go, and ``equipose_format`` becomes 3. Other graphs are left as they
    are. Returns {input name: the graph value it replaced}."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    from equipose.core.kernel_weights import layer_kernel_aug, rows_name, weights_name
    from equipose.core.presets import ModelConfig
    from equipose.runtime.session import INPUT_NAME

    meta = {p.key: p.value for p in proto.metadata_props}
    if meta.get("equipose_format") != "2" or "model_config" not in meta:
        return {}
    cfg = ModelConfig.from_dict(json.loads(meta["model_config"]))
    if not cfg.quotient:
        return {}
    graph = proto.graph
    inits = {t.name: t for t in graph.initializer}
    users = _consumers(graph)
    hats = _hat_products(graph, inits, users)
    if len(hats) != len(cfg.layers):
        raise ModelFormatError(f"found {len(hats)} kernel-correlation MatMuls for {len(cfg.layers)} layers; "
                               "not an equipose quotient graph")
    cut = {}
    for layer, ((mm, relu), L) in enumerate(zip(hats, cfg.layers)):
        aug = numpy_helper.to_array(inits[mm.input[0]])
        if not np.abs(aug - layer_kernel_aug(L)).max() <= _KERNEL_AUG_ATOL:
            raise ModelFormatError(f"layer {layer}: the graph's kernel constants are not the layer's kernel points "
                                   f"(radius {L.kernel_radius:g}, sigma {L.sigma:g}); not an equipose quotient graph")
        cut[weights_name(layer)] = relu.output[0]
    hat_layer = {mm.name: layer for layer, (mm, _) in enumerate(hats)}
    for node in graph.node:
        is_rows = node.op_type == "Gather" and node.input[1] not in inits and \
            any(a.name == "axis" and a.i == 1 for a in node.attribute)
        layer = _layer_of_rows(node.input[1], users, hat_layer) if is_rows else None
        if layer:
            cut.setdefault(rows_name(layer), node.input[1])
    expected = {weights_name(i) for i in range(len(cfg.layers))} | {rows_name(i) for i in range(1, len(cfg.layers))}
    if set(cut) != expected:
        raise ModelFormatError(f"kernel inputs found {sorted(cut)}, expected {sorted(expected)}; not an equipose "
                               "quotient graph")
    rename = {old: new for new, old in cut.items()}
    for node in graph.node:
        node.input[:] = [rename.get(n, n) for n in node.input]
        node.output[:] = [rename.get(n, n) for n in node.output]
    shapes = {}
    for i, L in enumerate(cfg.layers):
        shapes[weights_name(i)] = (TensorProto.FLOAT, ["batch", L.points_out, 13, L.neighbours])
        if i:
            shapes[rows_name(i)] = (TensorProto.INT64, [f"batch_x_{L.points_out * L.neighbours}"])
    kept = [vi for vi in graph.value_info if vi.name not in rename]
    del graph.value_info[:]
    graph.value_info.extend(kept + [helper.make_tensor_value_info(n, *shapes[n]) for n in cut])
    outputs = [o.name for o in graph.output]
    sub = extract_graph(proto, [INPUT_NAME] + sorted(cut), outputs, {**meta, "equipose_format": "3"})
    points = next(i for i in graph.input if i.name == INPUT_NAME)
    del sub.graph.input[:]
    sub.graph.input.append(points)
    for name in [weights_name(i) for i in range(len(cfg.layers))] + [rows_name(i) for i in range(1, len(cfg.layers))]:
        sub.graph.input.append(helper.make_tensor_value_info(name, *shapes[name]))
    del sub.graph.value_info[:]
    onnx.checker.check_model(sub, full_check=True)
    proto.CopyFrom(sub)
    return cut


def _class_chain_end(name: str, users: dict, outputs: set) -> str:
    """The last value of the single-consumer chain of ``_CLASS_CHAIN_OPS`` that starts at ``name``."""
    while name not in outputs:
        nxt = users.get(name, [])
        if len(nxt) != 1 or nxt[0].op_type not in _CLASS_CHAIN_OPS:
            return name
        name = nxt[0].output[0]
    return name


def _static_shape(vi) -> tuple:
    """A value's shape, symbolic dims as None."""
    return tuple(d.dim_value if d.HasField("dim_value") else None for d in vi.type.tensor_type.shape.dim)


def class_weights_as_inputs(proto, layers=None) -> dict:
    """Cut a format-3 graph one step later for the ``layers`` (indices; None: all), at their class-summed kernel
    weights: these become the inputs ``class_weights_<l>`` (``equipose.core.kernel_weights``: layer 0 [batch, P2,
    12, 5], layer l ≥ 1 [12, batch · P2, 5, nn]) in place of ``kernel_weights_<l>``, the ``neighbour_rows_<l>``
    stay, and ``equipose_format`` becomes 4. Layers already cut and graphs of other formats are left as they are.
    Returns {input name: the graph value it replaced}.

    Each ``kernel_weights_<l>`` must be read by one MatMul with the constant ``CLASS_MATRIX``; the cut follows it
    through ReduceSum / Reshape / Transpose to the value the next op reads, whose inferred shape must be the layout
    above."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper, shape_inference

    from equipose.core.kernel_weights import (CLASS_MATRIX, KERNEL_CLASSES, VERTICES, class_name,
                                              kernel_input_names, weights_name)
    from equipose.core.presets import ModelConfig
    from equipose.runtime.session import INPUT_NAME

    meta = {p.key: p.value for p in proto.metadata_props}
    if meta.get("equipose_format") not in ("3", "4") or "model_config" not in meta:
        return {}
    cfg = ModelConfig.from_dict(json.loads(meta["model_config"]))
    graph = proto.graph
    given = {i.name: i for i in graph.input}
    todo = [i for i in (range(len(cfg.layers)) if layers is None else layers) if weights_name(i) in given]
    if not todo:
        return {}
    inferred = shape_inference.infer_shapes(proto)
    shapes = {vi.name: _static_shape(vi) for vi in list(inferred.graph.value_info) + list(inferred.graph.input)}
    inits = {t.name: t for t in graph.initializer}
    users = _consumers(graph)
    outputs = {o.name for o in graph.output}
    cut, types = {}, {}
    for layer in todo:
        L, name = cfg.layers[layer], weights_name(layer)
        mm = users.get(name, [])
        if len(mm) != 1 or mm[0].op_type != "MatMul" or mm[0].input[1] != name or mm[0].input[0] not in inits or \
                not np.array_equal(numpy_helper.to_array(inits[mm[0].input[0]]), CLASS_MATRIX):
            raise ModelFormatError(f"{name} is not read by one MatMul with the kernel-class matrix; not an equipose "
                                   "format-3 quotient graph")
        end = _class_chain_end(mm[0].output[0], users, outputs)
        if layer == 0:
            want = (None, L.points_out, VERTICES, KERNEL_CLASSES)
            dims = ["batch", L.points_out, VERTICES, KERNEL_CLASSES]
        else:
            want = (VERTICES, None, KERNEL_CLASSES, L.neighbours)
            dims = [VERTICES, f"batch_x_{L.points_out}", KERNEL_CLASSES, L.neighbours]
        if shapes.get(end) != want:
            raise ModelFormatError(f"layer {layer}: the class weights {end!r} have shape {shapes.get(end)}, expected "
                                   f"{want}; not an equipose format-3 quotient graph")
        cut[class_name(layer)] = end
        types[class_name(layer)] = helper.make_tensor_value_info(class_name(layer), TensorProto.FLOAT, dims)
    rename = {old: new for new, old in cut.items()}
    for node in graph.node:
        node.input[:] = [rename.get(n, n) for n in node.input]
        node.output[:] = [rename.get(n, n) for n in node.output]
    kept = [vi for vi in graph.value_info if vi.name not in rename]
    del graph.value_info[:]
    graph.value_info.extend(kept + list(types.values()))
    classes = {i for i in range(len(cfg.layers)) if class_name(i) in given or class_name(i) in cut}
    order = kernel_input_names(cfg.layers, classes)
    sub = extract_graph(proto, [INPUT_NAME] + order, [o.name for o in graph.output], {**meta, "equipose_format": "4"})
    del sub.graph.input[:]
    sub.graph.input.extend([given[INPUT_NAME]] + [types[n] if n in types else given[n] for n in order])
    del sub.graph.value_info[:]
    onnx.checker.check_model(sub, full_check=True)
    proto.CopyFrom(sub)
    return cut


def extract_graph(proto, inputs: list, outputs: list, meta: dict):
    """The part of ``proto``'s graph from ``inputs`` to ``outputs`` (onnx's ``Extractor``) as a model with
    ``proto``'s IR version, producer, doc string and opsets, and the metadata ``meta`` ({key: str})."""
    from onnx.utils import Extractor
    sub = Extractor(proto).extract_model(list(inputs), list(outputs))
    for field in ("ir_version", "producer_name", "producer_version", "doc_string"):
        setattr(sub, field, getattr(proto, field))
    del sub.opset_import[:]
    sub.opset_import.extend(proto.opset_import)
    del sub.metadata_props[:]
    for k, v in meta.items():
        sub.metadata_props.add(key=k, value=v)
    return sub


def rewrite_model(proto, *, kernel_inputs: bool = True, class_layers=CLASS_LAYERS) -> dict:
    """Every rewrite of this module on ``proto`` (in place, metadata entry ``dropped_biases`` merged); returns
    {rewrite: what it removed}. ``kernel_inputs=False`` keeps a format-2 graph's neighbourhood inputs;
    ``class_layers``: the layers whose kernel weights enter summed per class (``class_weights_as_inputs``; () stops
    at format 3)."""
    dropped = drop_normalised_biases(proto)
    if dropped:
        entry = next((p for p in proto.metadata_props if p.key == "dropped_biases"), None)
        if entry is None:
            entry = proto.metadata_props.add(key="dropped_biases", value="{}")
        entry.value = json.dumps({**json.loads(entry.value), **dropped}, sort_keys=True)
    cut = kernel_weights_as_inputs(proto) if kernel_inputs else {}
    classes = class_weights_as_inputs(proto, class_layers) if kernel_inputs and class_layers else {}
    return {"drop_normalised_biases": dropped, "kernel_weights_as_inputs": cut, "class_weights_as_inputs": classes}


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
    outs = []
    for proto, sess in zip((before, after), sessions):                          # each fed as the runtime feeds it
        io = GraphIO(sess, {p.key: p.value for p in proto.metadata_props})
        outs.append(dict(zip(io.outputs, sess.run(io.outputs, io.feeds(x)))))
    return max(float(np.max(np.abs(outs[0][k] - outs[1][k]))) for k in outs[0])


def rewrite_model_file(path, out=None, atol: float | None = None, class_layers=CLASS_LAYERS) -> dict:
    """Rewrite an exported model file (fp32 or int8) and write it to ``out`` (default: in place), metadata kept.

    Checks the rewritten graph against the original on random inputs: the largest output difference must stay
    within ``atol`` (default ``FP32_ATOL``, ``INT8_ATOL`` for an int8 file), else ``ModelFormatError`` and nothing is
    written. ``class_layers`` as in ``rewrite_model``. Returns {"removed": {rewrite: what it removed},
    "max_abs_diff": float}."""
    import onnx
    path = pathlib.Path(path)
    out = path if out is None else pathlib.Path(out)
    original = read_model_file(path)
    rewritten = onnx.ModelProto()
    rewritten.CopyFrom(original)
    removed = rewrite_model(rewritten, class_layers=class_layers)
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
    ap.add_argument("--class-layers", default=",".join(map(str, CLASS_LAYERS)),
                    help="layers whose kernel weights enter summed per kernel class (comma-separated indices, '' for "
                         "none; default %(default)s)")
    args = ap.parse_args(argv)
    class_layers = tuple(int(i) for i in args.class_layers.split(",") if i.strip())
    for f in args.files:
        res = rewrite_model_file(f, class_layers=class_layers)
        counts = ", ".join(f"{k} {len(v)}" for k, v in res["removed"].items())
        print(f"{f}: removed {counts}; max output difference {res['max_abs_diff']:.2g}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
