"""Exact graph rewrites (``equipose.export.graph_rewrite``): what is dropped, what must stay, the numeric check."""
import json
import pathlib

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from onnx import TensorProto, helper, numpy_helper  # noqa: E402

from equipose.errors import ModelFormatError  # noqa: E402
from equipose.export import graph_rewrite  # noqa: E402
from equipose.export.graph_rewrite import drop_normalised_biases, rewrite_model_file  # noqa: E402

MODELS = pathlib.Path(__file__).resolve().parents[1] / "sdk" / "models"
C = 4


def _branch(g, tag, rng, *, extra_reader=False, act_first=False):
    """x [2, 5, C] → MatMul → Add bias → (LeakyRelu) → Transpose → InstanceNormalization → out_<tag>."""
    w, b = rng.normal(size=(C, C)).astype(np.float32), rng.normal(size=C).astype(np.float32)
    s, o = rng.uniform(0.5, 1.5, C).astype(np.float32), rng.normal(size=C).astype(np.float32)
    for name, v in ((f"w{tag}", w), (f"b{tag}", b), (f"s{tag}", s), (f"o{tag}", o)):
        g["inits"].append(numpy_helper.from_array(v, name))
    g["nodes"] += [helper.make_node("MatMul", ["x", f"w{tag}"], [f"m{tag}"]),
                   helper.make_node("Add", [f"m{tag}", f"b{tag}"], [f"a{tag}"], name=f"add{tag}")]
    src = f"a{tag}"
    if act_first:
        g["nodes"].append(helper.make_node("LeakyRelu", [src], [f"r{tag}"]))
        src = f"r{tag}"
    g["nodes"] += [helper.make_node("Transpose", [src], [f"t{tag}"], perm=[0, 2, 1]),
                   helper.make_node("InstanceNormalization", [f"t{tag}", f"s{tag}", f"o{tag}"], [f"out{tag}"])]
    g["outputs"].append(f"out{tag}")
    if extra_reader:                                       # the biased value is also an output: the bias matters
        g["outputs"].append(f"a{tag}")


def _model(rng):
    g = {"nodes": [], "inits": [], "outputs": []}
    _branch(g, "0", rng)
    _branch(g, "1", rng, extra_reader=True)
    _branch(g, "2", rng, act_first=True)
    graph = helper.make_graph(g["nodes"], "g", [helper.make_tensor_value_info("x", TensorProto.FLOAT, [2, 5, C])],
                              [helper.make_tensor_value_info(n, TensorProto.FLOAT,
                                                             [2, 5, C] if n[0] == "a" else [2, C, 5])
                               for n in g["outputs"]],
                              g["inits"])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def _run(proto, x):
    return ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"]).run(None, {"x": x})


def test_only_a_bias_the_normalisation_cancels_is_dropped():
    rng = np.random.default_rng(0)
    proto = _model(rng)
    before = onnx.ModelProto()
    before.CopyFrom(proto)
    assert drop_normalised_biases(proto) == {"b0": "w0"}    # add1 has a second reader, add2 a LeakyRelu first
    assert "b0" not in {t.name for t in proto.graph.initializer}
    onnx.checker.check_model(proto)
    x = rng.normal(size=(2, 5, C)).astype(np.float32)
    for a, b in zip(_run(before, x), _run(proto, x)):
        assert np.allclose(a, b, atol=1e-5)


def test_the_file_check_refuses_a_rewrite_that_changes_outputs(tmp_path, monkeypatch):
    src = tmp_path / "m.onnx"
    src.write_bytes((MODELS / "cup-tabletop.onnx").read_bytes())

    def drop_every_bias(proto, **options):                  # a wrong rewrite: removes a bias that matters
        inits = {t.name for t in proto.graph.initializer}
        node = [n for n in proto.graph.node if n.op_type == "Add" and any(i in inits for i in n.input)][-1]  # a head's
        for user in proto.graph.node:
            for i, name in enumerate(user.input):
                if name == node.output[0]:
                    user.input[i] = node.input[0]
        proto.graph.node.remove(node)
        return {"wrong": [node.name]}

    monkeypatch.setattr(graph_rewrite, "rewrite_model", drop_every_bias)
    with pytest.raises(ModelFormatError, match="differ"):
        rewrite_model_file(src, atol=1e-6)
    assert src.read_bytes() == (MODELS / "cup-tabletop.onnx").read_bytes()    # left as it was


@pytest.mark.parametrize("path", sorted(p for p in MODELS.glob("*.onnx") if not p.name.endswith(".int8.onnx")),
                         ids=lambda p: p.name)
def test_shipped_files_are_rewritten(path):
    from equipose.models.int8 import ensure_int8
    for f in (path, ensure_int8(path)):                                         # the fp32 file and its int8 copy
        proto = onnx.load(str(f))
        meta = {p.key: p.value for p in proto.metadata_props}
        assert meta["equipose_format"] == "4", f.name                           # kernel weights as inputs
        assert [i.name for i in proto.graph.input][1] == "class_weights_0"      # the first layer's class sums
        assert drop_normalised_biases(proto) == {}
        assert json.loads(meta["dropped_biases"])                               # the layers' weights named


@pytest.fixture(scope="module")
def quotient_format2(tmp_path_factory):
    """A random-weight ``edge-q`` model written as format 2 (the neighbourhoods as inputs)."""
    pytest.importorskip("torch")
    from equipose.export.onnx_export import export_random_model
    path = tmp_path_factory.mktemp("format2") / "q.onnx"
    export_random_model("edge-q", path, partial=True, category="mug", scale=0.2, format_version=2, verify=False)
    return path


@pytest.mark.parametrize("class_layers, fmt, nodes", [((), "3", 243), ((0,), "4", 240), ((0, 1, 2, 3), "4", 228)],
                         ids=["format-3", "format-4", "format-4-every-layer"])
def test_kernel_weights_become_inputs(quotient_format2, tmp_path, class_layers, fmt, nodes):
    from equipose.core.kernel_weights import kernel_input_names
    from equipose.core.presets import get_preset
    from equipose.runtime.estimator import PoseEstimator
    out = tmp_path / "q.onnx"
    res = rewrite_model_file(quotient_format2, out, class_layers=class_layers)
    before, after = onnx.load(str(quotient_format2)), onnx.load(str(out))
    layers = get_preset("edge-q").layers
    assert [i.name for i in after.graph.input] == ["points"] + kernel_input_names(layers, class_layers)
    assert {p.key: p.value for p in after.metadata_props}["equipose_format"] == fmt
    assert len(before.graph.node) == 318 and len(after.graph.node) == nodes    # measured on edge-q
    assert len(res["removed"]["kernel_weights_as_inputs"]) == 2 * len(layers) - 1
    assert sorted(res["removed"]["class_weights_as_inputs"]) == [f"class_weights_{i}" for i in class_layers]
    assert res["max_abs_diff"] <= 1e-5
    x = (np.random.default_rng(1).normal(size=(3, 256, 3)) * 0.3).astype(np.float32)
    a = PoseEstimator(quotient_format2, threads=1).run_model(x)
    b = PoseEstimator(out, threads=1).run_model(x)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], atol=1e-5)


def test_class_weights_of_more_layers_from_a_format4_file(tmp_path):
    from equipose.core.kernel_weights import kernel_input_names
    from equipose.core.presets import ModelConfig
    from equipose.runtime.estimator import PoseEstimator
    src = MODELS / "cup-tabletop.onnx"                                          # shipped: layer 0 as class sums
    out = tmp_path / "cup.onnx"
    res = rewrite_model_file(src, out, class_layers=(0, 1, 2, 3))
    assert sorted(res["removed"]["class_weights_as_inputs"]) == ["class_weights_1", "class_weights_2",
                                                                 "class_weights_3"]
    after = onnx.load(str(out))
    layers = ModelConfig.from_dict(json.loads({p.key: p.value for p in after.metadata_props}["model_config"])).layers
    assert [i.name for i in after.graph.input] == ["points"] + kernel_input_names(layers, (0, 1, 2, 3))
    x = (np.random.default_rng(2).normal(size=(2, 256, 3)) * 0.3).astype(np.float32)
    a = PoseEstimator(src, threads=1).run_model(x)
    b = PoseEstimator(out, threads=1).run_model(x)
    for k in a:
        np.testing.assert_allclose(a[k], b[k], atol=1e-5)


def test_kernel_rewrite_leaves_other_graphs(quotient_format2, tmp_path):
    pytest.importorskip("torch")
    from equipose.export.graph_rewrite import class_weights_as_inputs, kernel_weights_as_inputs
    from equipose.export.onnx_export import export_random_model
    tiny = export_random_model("tiny", tmp_path / "t.onnx", partial=True, category="mug", scale=0.2, verify=False)
    for path in (tiny, MODELS / "cup-tabletop.onnx"):                            # not quotient; already format 4
        proto = onnx.load(str(path))
        before = proto.SerializeToString()
        assert kernel_weights_as_inputs(proto) == {} and proto.SerializeToString() == before
        assert class_weights_as_inputs(proto, (0,)) == {} and proto.SerializeToString() == before
    proto = onnx.load(str(quotient_format2))                                     # format 2: not cut yet
    before = proto.SerializeToString()
    assert class_weights_as_inputs(proto) == {} and proto.SerializeToString() == before
