"""torch → ONNX export of an ``EquiPoseNet``: one self-contained file with the equipose metadata contract.

Convention:
    Inputs (format 2): ``points`` float32 [batch, N, 3], model units (metres / ``scale``), FPS-ordered; N fixed per
    model (metadata ``num_points``), batch dynamic; and one ``neighbours_<support>`` int64 [batch, centres, k] per
    neighbourhood of the layers (``equipose.core.neighbourhoods``). Outputs (DESIGN.md "The ONNX contract"):
    ``canonical_shape`` [batch, M, 3], ``hypothesis_rotations`` [batch, 60, 3, 3] (act on column vectors),
    ``hypothesis_translations`` [batch, 60, 3] (model units, input frame). Hypothesis j is the group rotation
    ``icosahedral.ANCHORS[j]`` (metadata ``anchors``). The runtime computes the neighbourhoods and the hypothesis
    scores (``equipose.core.neighbourhoods``, ``equipose.core.scores``): compiled, they take a fraction of the time of
    onnxruntime's TopK and MatMuls. Format 3 goes one step further: the graph is cut at each layer's kernel weights
    and gathered feature rows, which the runtime computes from the neighbourhoods (``equipose.core.kernel_weights``,
    the rewrite ``graph_rewrite.kernel_weights_as_inputs``); format 4 (the default for quotient presets) cuts the
    first layer after its kernel-class sums (``graph_rewrite.class_weights_as_inputs``).
    ``format_version=1`` writes the older contract (all inside the graph, one input); ``upgrade_model_file`` turns
    such a file into a format-2 one with the same network.
    The graph uses the default ONNX domain only; the group tables are constant int64 ``Gather`` indices.

Uses the torch 2.13 ``torch.export``-based exporter (``dynamo=True``, needs onnxscript) with weights inlined.
"""
from __future__ import annotations

import contextlib
import io
import logging
import pathlib
import sys
import warnings

import numpy as np

from equipose.core.errors import ConfigError, ModelFormatError
from equipose.core.metadata import encode_metadata, flush_negligible
from equipose.core.neighbourhoods import input_name, nearest_neighbourhoods, neighbourhood_specs
from equipose.export.graph_rewrite import CLASS_LAYERS, extract_graph, rewrite_model
from equipose.models.model_io import read_model_file, write_model_file
from equipose.runtime.session import GRAPH_OUTPUTS as OUTPUT_NAMES, INPUT_NAME, SCORES, GraphIO

__all__ = ["DEFAULT_OPSET", "OUTPUT_NAMES", "INPUT_NAME", "export_model", "export_random_model", "export_checkpoint",
           "update_metadata", "update_metadata_with_int8", "upgrade_model_file", "calibration_arrays", "op_type_counts"]

DEFAULT_OPSET = 20
MAX_BATCH = 4096          # upper bound declared for the dynamic batch dimension
PARITY_ATOL = 1e-4        # export-time self check: ORT vs torch on the example batch


def _contract_module(model, names=OUTPUT_NAMES, neighbour_inputs=()):
    """Wrap ``model`` so that forward takes the points and the ``neighbour_inputs`` (names, in order) and returns the
    outputs ``names`` as a tuple (what the exporter traces)."""
    import torch

    class _Contract(torch.nn.Module):
        def __init__(self, net):
            super().__init__()
            self.net = net

        def forward(self, points, *neighbours):          # points [B, N, 3]; neighbours [B, centres, k] int64 each
            given = dict(zip(neighbour_inputs, neighbours)) if neighbour_inputs else None
            out = self.net(points, neighbours=given)
            return tuple(out[k] for k in names)

    return _Contract(model).eval()


@contextlib.contextmanager
def _quiet_exporter():
    """Silence the exporter's progress prints (stdout), its torchvision registration log lines and warnings."""
    loggers = [logging.getLogger(n) for n in ("torch.onnx", "torch.onnx._internal.exporter._registration",
                                              "torch.export", "torch._export", "onnxscript")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    except BaseException:
        sys.stderr.write(buf.getvalue())                  # the exporter's own report helps when it fails
        raise
    finally:
        for lg, lv in zip(loggers, levels):
            lg.setLevel(lv)


def calibration_arrays(calibration) -> tuple:
    """Checkpoint calibration ``{"rotation": 3×3, "translation": 3}`` (or None = identity) → (R [3, 3], t [3])."""
    if calibration is None:
        return np.eye(3), np.zeros(3)
    if not isinstance(calibration, dict) or "rotation" not in calibration or "translation" not in calibration:
        raise ConfigError("calibration must be None or a dict with 'rotation' (3×3) and 'translation' (3), got "
                          f"{type(calibration).__name__}")
    R = np.asarray(calibration["rotation"], dtype=np.float64)
    t = np.asarray(calibration["translation"], dtype=np.float64)
    if R.shape != (3, 3) or t.shape != (3,) or not (np.isfinite(R).all() and np.isfinite(t).all()):
        raise ConfigError(f"calibration rotation must be finite 3×3 and translation finite 3, got {R.shape}, {t.shape}")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
        raise ConfigError("calibration rotation is not a proper rotation matrix (RᵀR ≠ I or det < 0)")
    return R, t


def op_type_counts(model_proto) -> dict:
    """``{op_type: count}`` over the top-level graph nodes, most frequent first."""
    counts: dict = {}
    for node in model_proto.graph.node:
        key = node.op_type if node.domain in ("", "ai.onnx") else f"{node.domain}::{node.op_type}"
        counts[key] = counts.get(key, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def flush_negligible_initializers(proto) -> int:
    """Set every float32 initializer value below 1e-12 × its tensor's largest magnitude (subnormals always) to 0, in
    place (``equipose.core.metadata.flush_negligible``): trained weights that decayed that far give subnormal products,
    which onnxruntime computes ~100× slower on x86 CPUs without flush-to-zero. Returns how many values changed."""
    from onnx import TensorProto, numpy_helper

    changed = 0
    for k, init in enumerate(proto.graph.initializer):
        if init.data_type != TensorProto.FLOAT or not init.dims:
            continue
        a = numpy_helper.to_array(init)
        flushed = flush_negligible(a)
        n = int(np.count_nonzero(flushed != a))
        if n:
            proto.graph.initializer[k].CopyFrom(numpy_helper.from_array(flushed, init.name))
            changed += n
    return changed


def _drop_initializer_value_info(proto):
    """Remove ``value_info`` entries of initializers (the exporter writes them; they go stale when a tool such as
    onnxruntime's quantizer transposes a weight in place, and then shape inference fails)."""
    inits = {t.name for t in proto.graph.initializer}
    keep = [vi for vi in proto.graph.value_info if vi.name not in inits]
    del proto.graph.value_info[:]
    proto.graph.value_info.extend(keep)


def export_model(model, path, *, category: str, scale: float, symmetry: str = "none", calibration=None, handle=None,
                 shape_prior: str | None = None,
                 random_init: bool = False, training: dict | None = None, metrics: dict | None = None,
                 opset: int = DEFAULT_OPSET, verify: bool = True, format_version: int | None = None) -> pathlib.Path:
    """Export an ``EquiPoseNet`` to a single self-describing ONNX file and return its path.

    Args:
        model: ``equipose.train.EquiPoseNet`` (exported in eval mode; its training flag is restored).
        path: output ``.onnx`` file (parent folders are created; written atomically).
        category, scale (metres per model unit), symmetry, calibration ({"rotation", "translation"} or None),
        handle ([3] handle direction in the category frame, or None), shape_prior ("cylinder", "open_cylinder" or
            None), random_init, training, metrics: written to ``metadata_props`` via ``equipose.core.metadata.encode_metadata``.
        opset: ONNX opset of the default domain.
        verify: run the file once in onnxruntime on the export example and compare with torch (max abs ≤ 1e-4).
        format_version: 4 (as 3, with the first layer's kernel weights summed per kernel class; quotient presets
            only), 3 (each layer's kernel weights and feature rows as inputs, no scores in the graph; quotient
            presets only), 2 (the neighbourhoods as inputs, no scores in the graph) or 1 (both computed in the graph,
            for readers of the ONNX file that do not compute them); None: 4 for a quotient preset, else 2. The SDK
            runs all four.
    Raises:
        ConfigError / MetadataError for bad arguments; RuntimeError if the exported graph disagrees with torch.
    """
    import onnx
    import torch

    from equipose.train.network.model import EquiPoseNet

    if not isinstance(model, EquiPoseNet):
        raise ConfigError(f"export_model needs an equipose.train.EquiPoseNet, got {type(model).__name__}")
    if not isinstance(category, str) or not category.strip():
        raise ConfigError("category must be a non-empty string (e.g. 'airplane', 'mug')")
    try:
        scale = float(scale)
    except (TypeError, ValueError):
        raise ConfigError(f"scale must be a number (metres per model unit), got {scale!r}") from None
    if not (np.isfinite(scale) and scale > 0):
        raise ConfigError(f"scale must be a positive finite number of metres per model unit, got {scale}")
    cal_R, cal_t = calibration_arrays(calibration)
    cfg = model.config
    meta = encode_metadata(category=category, preset=cfg.name, model_config=cfg.to_dict(), num_points=cfg.num_points,
                           num_canonical_points=cfg.num_canonical_points, scale=scale, partial=model.partial,
                           symmetry=symmetry, calibration_rotation=cal_R, calibration_translation=cal_t,
                           random_init=random_init, training=training, metrics=metrics, handle=handle,
                           shape_prior=shape_prior)
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)

    was_training = model.training
    if format_version is None:
        format_version = 4 if cfg.quotient else 2
    if format_version not in (1, 2, 3, 4):
        raise ConfigError(f"format_version must be 1, 2, 3 or 4, got {format_version!r}")
    if format_version >= 3 and not cfg.quotient:
        raise ConfigError(f"format {format_version} (kernel weights as inputs) needs a quotient preset; {cfg.name!r} "
                          "is not one: export it with format_version=2")
    specs = neighbourhood_specs(cfg.layers) if format_version >= 2 else []
    neighbour_inputs = [input_name(sp) for sp in specs]
    names = OUTPUT_NAMES + ((SCORES,) if format_version == 1 else ())
    meta["equipose_format"] = str(min(format_version, 2))                 # formats 3, 4: rewrites of format 2
    wrapper = _contract_module(model, names, neighbour_inputs)            # sets eval mode on the net
    gen = torch.Generator().manual_seed(1234)
    example = torch.randn(2, cfg.num_points, 3, generator=gen) * 0.2       # [2, N, 3]; batch 2 keeps the dim symbolic
    inputs = (example,) + tuple(torch.from_numpy(nearest_neighbourhoods(example.numpy(), sp)) for sp in specs)
    batch = torch.export.Dim("batch", min=1, max=MAX_BATCH)
    try:
        with _quiet_exporter(), torch.no_grad():
            program = torch.onnx.export(wrapper, inputs, None, dynamo=True, external_data=False,
                                        input_names=[INPUT_NAME] + neighbour_inputs,
                                        output_names=list(names),
                                        dynamic_shapes=({0: batch},) + ((tuple({0: batch} for _ in specs),)
                                                                         if specs else ()),   # (points, *neighbours)
                                        opset_version=int(opset), optimize=True)
        proto = program.model_proto
    finally:
        model.train(was_training)
    proto.doc_string = (f"equipose {cfg.name} model for category {category!r}: points [batch, {cfg.num_points}, 3] "
                        "(model units) -> canonical shape + 60 pose hypotheses")
    _drop_initializer_value_info(proto)
    del proto.metadata_props[:]
    for k, v in meta.items():
        proto.metadata_props.add(key=k, value=v)
    rewrite_model(proto, kernel_inputs=format_version >= 3,                # exact rewrites (graph_rewrite)
                  class_layers=CLASS_LAYERS if format_version == 4 else ())
    flush_negligible_initializers(proto)
    onnx.checker.check_model(proto, full_check=True)
    write_model_file(proto, path)
    if verify:
        _verify_parity(wrapper, path, example, specs)
    return path


def _verify_parity(wrapper, path: pathlib.Path, example, specs):
    """Run the written file in onnxruntime on ``example`` [B, N, 3] as the runtime does (``GraphIO``: neighbourhoods
    or kernel inputs and hypothesis scores computed outside a format-2, -3 or -4 graph) and compare all four outputs
    with torch given the same neighbourhoods (``specs``: the model's, none for format 1)."""
    import onnxruntime as ort
    import torch

    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    io = GraphIO(sess, dict(sess.get_modelmeta().custom_metadata_map), path.name)
    x = example.numpy()
    feeds = io.feeds(x)
    got = io.complete(dict(zip(io.outputs, sess.run(io.outputs, feeds))), x)
    given = {input_name(sp): torch.from_numpy(nearest_neighbourhoods(x, sp)) for sp in specs} or None
    with torch.no_grad():
        ref = {k: v.numpy() for k, v in wrapper.net(example, neighbours=given).items()}
    errs = {n: float(np.abs(got[n] - ref[n]).max()) for n in OUTPUT_NAMES + (SCORES,)}
    bad = {n: e for n, e in errs.items() if not e <= PARITY_ATOL}
    if bad:
        raise RuntimeError(f"exported {path} disagrees with torch beyond {PARITY_ATOL}: {bad}")


def export_random_model(preset, path, partial: bool = True, category: str = "unknown", scale: float = 2.0,
                        seed: int = 0, **kwargs) -> pathlib.Path:
    """Export a randomly initialised model of ``preset`` (tests, benchmarks, demo placeholder); ``random_init`` set."""
    import torch

    from equipose.train.network.model import EquiPoseNet

    torch.manual_seed(int(seed))
    try:
        model = EquiPoseNet(preset, partial=partial)
    except ValueError as e:                                                # unknown preset name
        raise ConfigError(str(e)) from None
    training = {"random_init": True, "seed": int(seed), "mode": "partial" if partial else "complete"}
    return export_model(model.eval(), path, category=category, scale=scale, random_init=True,
                        training=kwargs.pop("training", training), **kwargs)


MAX_LIST_IN_METADATA = 32


def _summary_of(training: dict) -> dict:
    """The checkpoint's training dict without per-step logs (lists longer than 32 entries, e.g. step times),
    which would bloat every model file; their names are listed under ``"omitted"``."""
    keep, omitted = {}, []
    for k, v in training.items():
        if isinstance(v, (list, tuple)) and len(v) > MAX_LIST_IN_METADATA:
            omitted.append(k)
        else:
            keep[k] = v
    if omitted:
        keep["omitted"] = omitted
    return keep


def export_checkpoint(checkpoint, path, *, category: str | None = None, scale: float | None = None,
                      **kwargs) -> pathlib.Path:
    """Export a training checkpoint (``equipose.train.checkpoint`` format) with its category, scale, symmetry,
    calibration, training summary and metrics. ``category`` / ``scale`` (metres per model unit) override the
    checkpoint's (the training summary then records the original as ``trained_category`` / ``trained_scale``)."""
    from equipose.train.fitting.checkpoint import model_from_checkpoint

    checkpoint = pathlib.Path(checkpoint)
    if not checkpoint.is_file():
        raise ConfigError(f"checkpoint {checkpoint} does not exist (train one with 'equipose train', or export "
                          "random weights with 'equipose export --preset P --random-init')")
    try:
        model, ckpt = model_from_checkpoint(checkpoint)
    except Exception as e:                                                 # pickle, key, shape mismatches
        raise ModelFormatError(f"{checkpoint} is not a readable equipose checkpoint: {e}") from None
    training = _summary_of(ckpt.get("training") or {})
    training.setdefault("step", int(ckpt.get("step", 0)))
    training.setdefault("mode", "partial" if model.partial else "complete")
    if category is not None and category != ckpt.get("category"):
        training["trained_category"] = ckpt.get("category")
    if scale is not None and scale != ckpt.get("scale"):
        training["trained_scale"] = ckpt.get("scale")
    from equipose.train.data.tabletop import TABLETOP
    category = category or ckpt.get("category", "unknown")               # e.g. a cup network exported as "mug"
    spec = TABLETOP.get(category)
    kwargs.setdefault("handle", (1.0, 0.0, 0.0) if spec is not None and spec.handle else None)
    kwargs.setdefault("shape_prior", "cylinder" if category == "can" else "open_cylinder" if category in ("cup", "mug")
                      else None)
    return export_model(model, path, category=category,
                        scale=scale if scale is not None else ckpt.get("scale", 1.0),
                        symmetry=ckpt.get("symmetry", "none"), calibration=ckpt.get("calibration"),
                        random_init=False, training=training, metrics=ckpt.get("metrics") or {}, **kwargs)


def _topk_neighbourhoods(proto, specs) -> dict:
    """{TopK indices output name: its ``NeighbourhoodSpec``} for the kNN TopKs of a format-1 graph, matched by the
    shape of the ranked distances [batch, centres, support] and k."""
    import onnx
    from onnx import numpy_helper

    inferred = onnx.shape_inference.infer_shapes(proto)
    dims = {v.name: [d.dim_value if d.HasField("dim_value") else d.dim_param for d in v.type.tensor_type.shape.dim]
            for v in inferred.graph.value_info}
    values = {t.name: numpy_helper.to_array(t) for t in proto.graph.initializer}
    values.update({n.output[0]: numpy_helper.to_array(n.attribute[0].t) for n in proto.graph.node
                   if n.op_type == "Constant" and n.attribute and n.attribute[0].name == "value"})
    found = {}
    for node in proto.graph.node:
        if node.op_type != "TopK":
            continue
        shape, k = dims.get(node.input[0]), values.get(node.input[1])
        match = [sp for sp in specs if shape is not None and k is not None and shape[1:] == [sp.centres, sp.support]
                 and int(np.asarray(k).reshape(-1)[0]) == sp.k]
        if len(match) != 1:
            raise ModelFormatError(f"TopK {node.name} over {shape} (k = {k}) matches no neighbourhood of the model's "
                                   f"layers {specs}; re-export the model instead")
        found[node.output[1]] = match[0]
    if sorted(found.values(), key=lambda sp: sp.support) != sorted(specs, key=lambda sp: sp.support):
        raise ModelFormatError(f"the graph's TopKs {sorted(found.values(), key=str)} are not the model's "
                               f"neighbourhoods {specs}; re-export the model instead")
    return found


def upgrade_model_file(path, out=None) -> pathlib.Path:
    """A format-1 model file → format 2 with the same network: each kNN TopK becomes the graph input
    ``neighbours_<support>``, the score nodes go, every metadata entry is kept and ``equipose_format`` set to 2.
    Written to ``out`` (default: in place); a format-2 file is copied unchanged. Works on fp32 and int8 files alike
    (neither the TopKs nor the score nodes hold weights)."""
    import json

    import onnx
    from onnx import TensorProto, helper

    from equipose.core.presets import ModelConfig

    path = pathlib.Path(path)
    out = path if out is None else pathlib.Path(out)
    proto = read_model_file(path)
    meta = {p.key: p.value for p in proto.metadata_props}
    outputs = [o.name for o in proto.graph.output]
    if not set(OUTPUT_NAMES) <= set(outputs) or "model_config" not in meta:
        raise ModelFormatError(f"{path}: outputs {outputs} lack {OUTPUT_NAMES} or it has no equipose metadata; "
                               "not an equipose model")
    if meta.get("equipose_format") == "1":
        specs = neighbourhood_specs(ModelConfig.from_dict(json.loads(meta["model_config"])).layers)
        topk = _topk_neighbourhoods(proto, specs)
        for node in proto.graph.node:                                      # consumers read the new inputs
            for i, name in enumerate(node.input):
                if name in topk:
                    node.input[i] = input_name(topk[name])
        for sp in specs:
            proto.graph.input.append(helper.make_tensor_value_info(input_name(sp), TensorProto.INT64,
                                                                   ["batch", sp.centres, sp.k]))
        meta["equipose_format"] = "2"
        sub = extract_graph(proto, [INPUT_NAME] + [input_name(sp) for sp in specs], OUTPUT_NAMES, meta)
        onnx.checker.check_model(sub, full_check=True)
        proto = sub
    write_model_file(proto, out)
    return out


def update_metadata(path, **values) -> pathlib.Path:
    """Rewrite metadata entries of an exported model in place (dicts are stored as JSON), e.g. ``metrics=`` after an
    evaluation of that very file. The result is re-validated with ``equipose.core.metadata.decode_metadata``.

    On an int8 copy built from the fp32 file beside it (``equipose.models.int8``) an entry that differs from the fp32
    file's is recorded in that file's ``int8_overrides`` (one equal to it clears the override, so the copy follows
    the fp32 file again) and the copy is rebuilt, so that a later rebuild keeps them."""
    import json

    from equipose.core.metadata import decode_metadata
    from equipose.models.int8 import OVERRIDES_KEY, ensure_int8, fp32_path_for, is_derived_int8, quantize_int8

    path = pathlib.Path(path)
    if fp32_path_for(path) is not None and fp32_path_for(path).is_file():
        ensure_int8(fp32_path_for(path))                                    # an int8 copy not built yet, or stale
    encoded = {k: json.dumps(v) if isinstance(v, (dict, list)) else str(v) for k, v in values.items()}
    target = fp32_path_for(path) if is_derived_int8(path) else path
    proto = read_model_file(target)
    meta = {p.key: p.value for p in proto.metadata_props}
    if target != path:
        overrides = json.loads(meta.get(OVERRIDES_KEY) or "{}")
        for k, v in encoded.items():
            if meta.get(k) == v:
                overrides.pop(k, None)
            else:
                overrides[k] = v
        decode_metadata({**meta, **overrides}, source=str(path))            # the int8 copy's view of it
        encoded = {OVERRIDES_KEY: json.dumps(overrides, sort_keys=True)}
    meta.update(encoded)
    decode_metadata(meta, source=str(target))
    del proto.metadata_props[:]
    for k, v in meta.items():
        proto.metadata_props.add(key=k, value=v)
    write_model_file(proto, target)
    return quantize_int8(target, path) if target != path else path


def update_metadata_with_int8(path, **values) -> pathlib.Path:
    """``update_metadata`` of an fp32 model file, and of its ``.int8`` sibling where that is a stand-alone file (an
    int8 copy built from the fp32 file inherits the entries when it is rebuilt)."""
    from equipose.models.int8 import int8_path_for, is_derived_int8

    out = update_metadata(path, **values)
    sibling = int8_path_for(path)
    if sibling.is_file() and not is_derived_int8(sibling):
        update_metadata(sibling, **values)
    return out
