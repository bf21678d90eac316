"""ONNX export tests: checker + shape inference, op allowlist, ORT-vs-torch parity for every preset, equivariance
through onnxruntime alone, metadata round trip, dynamic batch, int8 copy, CLI and its errors."""
import hashlib
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")

from equipose.core import icosahedral as I  # noqa: E402
from equipose.cli import main as cli_main  # noqa: E402
from equipose.errors import ConfigError, MetadataError, ModelFormatError  # noqa: E402
from equipose.export import (export_checkpoint, export_model, export_random_model, int8_path_for,  # noqa: E402
                              upgrade_model_file)
from equipose.core.metadata import REQUIRED_KEYS, decode_metadata  # noqa: E402
from equipose.core.neighbourhoods import input_name, neighbourhood_specs  # noqa: E402
from equipose.core.presets import get_preset  # noqa: E402
from equipose.testing import assert_equivariant, onnx_model_fn  # noqa: E402
from equipose.train.fitting.checkpoint import save_checkpoint  # noqa: E402
from equipose.train.network.model import EquiPoseNet  # noqa: E402

OUTPUTS = ("canonical_shape", "hypothesis_rotations", "hypothesis_translations")             # the graph's (format 2)
ALL_OUTPUTS = OUTPUTS + ("hypothesis_scores",)                                              # with the runtime's scores
# Every op the exporter may emit. Deliberately absent: Loop, Scan, If, GatherND, GatherElements, custom domains.
ALLOWED_OPS = {"InstanceNormalization", 
    "Add", "BatchNormalization", "Cast", "Clip", "Concat", "Constant", "Div", "Expand", "Gather", "Gemm",
    "LeakyRelu", "MatMul", "Max", "Min", "Mul", "Neg", "Pow", "Range", "Reciprocal", "ReduceL2", "ReduceMax",
    "ReduceMean", "ReduceMin", "ReduceSum", "Relu", "Reshape", "Shape", "Sigmoid", "Slice", "Sqrt", "Squeeze", "Sub",
    "TopK", "Transpose", "Unsqueeze", "Where",
}
CALIBRATION = {"rotation": [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], "translation": [0.01, -0.02, 0.03]}


def _cloud(rng, b, n):
    return (rng.normal(size=(b, n, 3)) * [0.25, 0.15, 0.1] + [0.1, -0.05, 0.3]).astype(np.float32)


def _session(path):
    so = ort.SessionOptions()
    so.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), so, providers=["CPUExecutionProvider"])


def _torch_outputs(model, x):
    with torch.no_grad():
        out = model(torch.from_numpy(x))
    return [out[k].numpy() for k in ALL_OUTPUTS]


def _onnx_outputs(path, x):
    """The four outputs as the SDK sees them: the graph's and the runtime's hypothesis scores."""
    out = onnx_model_fn(_session(path))(x)
    return [out[k] for k in ALL_OUTPUTS]


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory):
    """A tiny partial-mode model saved as a checkpoint (calibration, symmetry, metrics) and exported from it."""
    d = tmp_path_factory.mktemp("export_tiny")
    torch.manual_seed(7)
    model = EquiPoseNet("tiny", partial=True).eval()
    with torch.no_grad():                                   # non-trivial BatchNorm statistics
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.uniform_(-0.1, 0.1)
                m.running_var.uniform_(0.5, 1.5)
    ckpt = save_checkpoint(d / "tiny.pt", model, category="mug", scale=0.25, symmetry="continuous:z", step=42,
                           calibration=CALIBRATION,
                           training={"dataset": "synthetic", "mode": "partial", "step_seconds": [0.5] * 100},
                           metrics={"rot_err_median_deg": 12.5})
    path = export_checkpoint(ckpt, d / "tiny.onnx", verify=False)
    return model, path


@pytest.fixture(scope="module")
def tiny_cli(tmp_path_factory):
    """A tiny complete-mode random model exported through the CLI with --int8."""
    d = tmp_path_factory.mktemp("export_cli")
    out = d / "m.onnx"
    rc = cli_main(["export", "--preset", "tiny", "--random-init", "--mode", "complete", "--category", "bowl",
                   "--scale", "0.5", "--seed", "3", "-o", str(out), "--int8"])
    assert rc == 0
    torch.manual_seed(3)
    return EquiPoseNet("tiny", partial=False).eval(), out


def test_checker_and_shape_inference(tiny_ckpt):
    _, path = tiny_ckpt
    onnx.checker.check_model(str(path), full_check=True)
    proto = onnx.load(str(path))
    assert not any(t.data_location == onnx.TensorProto.EXTERNAL for t in proto.graph.initializer)
    inferred = onnx.shape_inference.infer_shapes(proto, strict_mode=True, data_prop=True)

    def dims(vi):
        return [d.dim_param or d.dim_value for d in vi.type.tensor_type.shape.dim]

    cfg = get_preset("tiny")
    specs = neighbourhood_specs(cfg.layers)
    assert [dims(v) for v in inferred.graph.input] == [["batch", cfg.num_points, 3]] + [
        ["batch", s.centres, s.k] for s in specs]
    assert [v.name for v in inferred.graph.input[1:]] == [input_name(s) for s in specs]
    assert {v.type.tensor_type.elem_type for v in inferred.graph.input[1:]} == {onnx.TensorProto.INT64}
    assert inferred.graph.input[0].name == "points"
    assert inferred.graph.input[0].type.tensor_type.elem_type == onnx.TensorProto.FLOAT
    assert [v.name for v in inferred.graph.output] == list(OUTPUTS)
    assert [dims(v) for v in inferred.graph.output] == [
        ["batch", cfg.num_canonical_points, 3], ["batch", 60, 3, 3], ["batch", 60, 3]]


def _check_graph_rules(path, cfg):
    proto = onnx.load(str(path))
    ops = [n.op_type for n in proto.graph.node]
    assert {n.domain for n in proto.graph.node} <= {"", "ai.onnx"}
    assert {o.domain for o in proto.opset_import} <= {"", "ai.onnx"}
    assert set(ops) <= ALLOWED_OPS, sorted(set(ops) - ALLOWED_OPS)
    for forbidden in ("Loop", "Scan", "If", "GatherND", "GatherElements"):
        assert forbidden not in ops
    inits = {t.name: t for t in proto.graph.initializer}
    consumers = {}
    for n in proto.graph.node:
        for i in n.input:
            consumers.setdefault(i, []).append(n)
    group_convs = 0
    for n in proto.graph.node:
        if n.op_type == "Gather" and n.input[1] in inits:
            idx = onnx.numpy_helper.to_array(inits[n.input[1]])
            assert idx.dtype == np.int64
            if idx.size == I.INTRA_NEIGHBOURS.size and np.array_equal(idx, I.INTRA_NEIGHBOURS.reshape(-1)):
                # Gather(const table) → Reshape → MatMul/Gemm (the dense group-conv weight)
                nxt = consumers[n.output[0]]
                assert [m.op_type for m in nxt] == ["Reshape"]
                assert {m.op_type for m in consumers[nxt[0].output[0]]} <= {"MatMul", "Gemm"}
                group_convs += 1
    n_layers = len(cfg.layers)
    assert group_convs == n_layers                          # one intra (group) conv per separable layer
    assert "TopK" not in ops                                # neighbourhoods are inputs, one per support size
    assert len(proto.graph.input) == 1 + len({L.points_in for L in cfg.layers})
    assert ops.count("Slice") >= sum(L.points_out < L.points_in for L in cfg.layers)   # prefix downsampling
    return proto


def test_op_allowlist_and_group_conv_structure(tiny_ckpt, tiny_cli):
    _check_graph_rules(tiny_ckpt[1], get_preset("tiny"))
    _check_graph_rules(tiny_cli[1], get_preset("tiny"))


def test_allowlist_rejects_forbidden_ops(tiny_ckpt, tmp_path):
    """The graph check must fail on a GatherND graph (guards against a check that cannot fail)."""
    proto = onnx.load(str(tiny_ckpt[1]))
    bad = onnx.helper.make_node("GatherND", ["points", "idx"], ["extra"])
    proto.graph.node.append(bad)
    onnx.save(proto, str(tmp_path / "bad.onnx"))
    with pytest.raises(AssertionError):
        _check_graph_rules(tmp_path / "bad.onnx", get_preset("tiny"))


def test_parity_tiny_partial_and_complete(tiny_ckpt, tiny_cli, rng):
    for model, path in (tiny_ckpt, tiny_cli):
        x = _cloud(rng, 2, model.num_points)
        got = _onnx_outputs(path, x)
        for name, a, b in zip(ALL_OUTPUTS, got, _torch_outputs(model, x)):
            assert a.shape == b.shape, name
            assert np.abs(a - b).max() <= 1e-4, (path.name, name, float(np.abs(a - b).max()))


def test_decayed_weights_are_zero_in_the_graph(tmp_path, rng):
    """Weights decayed to ~1e-38 (subnormal) or ~1e-30 (subnormal products) are exported as 0: onnxruntime computes
    subnormal products ~100× slower on x86 without flush-to-zero. The outputs keep parity with torch."""
    from onnx import numpy_helper
    torch.manual_seed(5)
    model = EquiPoseNet("tiny", partial=True).eval()
    weights = [p for p in model.parameters() if p.dim() == 2]
    with torch.no_grad():
        weights[0][:, 0] = 3e-39
        weights[-1][0, :] = 1e-30
    path = export_model(model, tmp_path / "decayed.onnx", category="mug", scale=0.25, verify=True)
    proto = onnx.load(str(path))
    for init in proto.graph.initializer:
        a = numpy_helper.to_array(init)
        if a.dtype == np.float32 and a.size > 1:
            small = (a != 0) & (np.abs(a) < 1e-12 * np.abs(a).max())
            assert not small.any(), init.name
    x = _cloud(rng, 2, model.num_points)
    for name, a, b in zip(ALL_OUTPUTS, _onnx_outputs(path, x), _torch_outputs(model, x)):
        assert np.abs(a - b).max() <= 1e-4, name


@pytest.mark.parametrize("preset", ["small", "paper"])
def test_parity_larger_presets(preset, tmp_path, rng):
    model_seed = {"small": 11, "paper": 12}[preset]
    path = export_random_model(preset, tmp_path / f"{preset}.onnx", seed=model_seed, verify=False)
    torch.manual_seed(model_seed)
    model = EquiPoseNet(preset, partial=True).eval()
    x = _cloud(rng, 1, model.num_points)
    got = _onnx_outputs(path, x)
    for name, a, b in zip(ALL_OUTPUTS, got, _torch_outputs(model, x)):
        assert np.abs(a - b).max() <= 1e-4, (preset, name, float(np.abs(a - b).max()))
    _check_graph_rules(path, get_preset(preset))
    meta = decode_metadata(_session(path).get_modelmeta().custom_metadata_map)
    assert meta["preset"] == preset and meta["num_points"] == get_preset(preset).num_points and meta["random_init"]


@pytest.mark.parametrize("which", ["partial", "complete"])
def test_equivariance_through_onnxruntime(which, tiny_ckpt, tiny_cli, rng):
    _, path = tiny_ckpt if which == "partial" else tiny_cli
    x = _cloud(rng, 2, get_preset("tiny").num_points)
    errs = assert_equivariant(onnx_model_fn(_session(path)), x, rotations=[1, 7, 19, 30, 44, 59], atol=1e-4)
    assert errs["max"] <= 1e-4


def test_equivariance_check_detects_a_broken_model(tiny_ckpt, rng):
    """Sanity of the harness on ONNX outputs: un-permuted scores must be reported as a violation."""
    fn = onnx_model_fn(_session(tiny_ckpt[1]))

    def broken(points):
        out = fn(points)
        out["hypothesis_scores"] = out["hypothesis_scores"] + points[:, :1, 0] * np.arange(60)
        return out

    with pytest.raises(AssertionError, match="hypothesis_scores"):
        assert_equivariant(broken, _cloud(rng, 1, 256), rotations=[5])


def test_metadata_round_trip(tiny_ckpt, tiny_cli):
    meta_map = _session(tiny_ckpt[1]).get_modelmeta().custom_metadata_map
    assert set(REQUIRED_KEYS) <= set(meta_map)
    meta = decode_metadata(meta_map)
    cfg = get_preset("tiny")
    assert meta["category"] == "mug" and meta["preset"] == "tiny" and meta["scale"] == 0.25
    assert meta["partial"] is True and meta["random_init"] is False and meta["symmetry"] == "continuous:z"
    assert meta["num_points"] == cfg.num_points and meta["num_canonical_points"] == cfg.num_canonical_points
    assert meta["model_config"] == json.loads(json.dumps(cfg.to_dict()))
    np.testing.assert_allclose(meta["calibration_rotation"], CALIBRATION["rotation"])
    np.testing.assert_allclose(meta["calibration_translation"], CALIBRATION["translation"])
    np.testing.assert_allclose(meta["anchors"], I.ANCHOR_QUATERNIONS, atol=1e-8)
    assert meta["metrics"] == {"rot_err_median_deg": 12.5}
    assert meta["training"]["dataset"] == "synthetic" and meta["training"]["step"] == 42
    assert "step_seconds" not in meta["training"] and meta["training"]["omitted"] == ["step_seconds"]

    cli_meta = decode_metadata(_session(tiny_cli[1]).get_modelmeta().custom_metadata_map)
    assert cli_meta["category"] == "bowl" and cli_meta["scale"] == 0.5 and cli_meta["partial"] is False
    assert cli_meta["random_init"] is True
    np.testing.assert_allclose(cli_meta["calibration_rotation"], np.eye(3))


def test_dynamic_batch(tiny_ckpt, rng):
    sess = _session(tiny_ckpt[1])
    x = _cloud(rng, 3, 256)
    one = [_onnx_outputs(tiny_ckpt[1], x[i:i + 1]) for i in range(3)]
    three = _onnx_outputs(tiny_ckpt[1], x)
    for k, name in enumerate(ALL_OUTPUTS):
        assert three[k].shape[0] == 3 and one[0][k].shape[0] == 1
        np.testing.assert_allclose(three[k], np.concatenate([o[k] for o in one]), atol=1e-5, err_msg=name)
    with pytest.raises(Exception):                           # N is fixed per model
        onnx_model_fn(sess)(_cloud(rng, 1, 128))


@pytest.mark.parametrize("partial", [True, False])
def test_format1_file_reads_and_upgrades_to_format2(partial, tmp_path, rng):
    """A format-1 file (kNN and scores in the graph) reads; ``upgrade_model_file`` makes it format 2 with the same
    network (neighbourhoods as inputs, no scores), and the runtime's neighbourhoods and scores give the same outputs."""
    from equipose import PoseEstimator

    torch.manual_seed(5)
    model = EquiPoseNet("tiny", partial=partial).eval()
    old = export_model(model, tmp_path / "f1.onnx", category="bowl", scale=0.3, format_version=1)
    new = upgrade_model_file(old, tmp_path / "f2.onnx")
    assert [o.name for o in _session(old).get_outputs()] == list(ALL_OUTPUTS)
    assert [o.name for o in _session(new).get_outputs()] == list(OUTPUTS)
    assert [i.name for i in _session(old).get_inputs()] == ["points"]
    assert [i.name for i in _session(new).get_inputs()] == ["points"] + [input_name(s) for s in
                                                                        neighbourhood_specs(model.config.layers)]
    assert "TopK" in {n.op_type for n in onnx.load(str(old)).graph.node}
    assert "TopK" not in {n.op_type for n in onnx.load(str(new)).graph.node}
    meta_old = dict(_session(old).get_modelmeta().custom_metadata_map)
    meta_new = dict(_session(new).get_modelmeta().custom_metadata_map)
    assert meta_old.pop("equipose_format") == "1" and meta_new.pop("equipose_format") == "2"
    assert meta_old == meta_new
    x = _cloud(rng, 3, model.num_points)
    graph = _session(old).run(list(ALL_OUTPUTS), {"points": x})
    runtime = _onnx_outputs(new, x)
    for name, a, b in zip(ALL_OUTPUTS, graph, runtime):
        np.testing.assert_allclose(b, a, atol=1e-5, err_msg=name)
    assert np.array_equal(graph[3].argmin(1), runtime[3].argmin(1))
    for name, a, b in zip(ALL_OUTPUTS, runtime, _torch_outputs(model, x)):
        assert np.abs(a - b).max() <= 1e-4, name
    scene = _cloud(rng, 1, 600)[0] * 0.3 + [0.0, 0.0, 0.8]
    r_old, r_new = (PoseEstimator(p, threads=1).predict_points(scene) for p in (old, new))
    np.testing.assert_allclose(r_new.rotation, r_old.rotation, atol=1e-6)
    np.testing.assert_allclose(r_new.translation, r_old.translation, atol=1e-6)


def test_cli_writes_either_format(tmp_path):
    for fmt, inputs in (("1", 1), ("2", 1 + len(neighbourhood_specs(get_preset("tiny").layers)))):
        out = tmp_path / f"f{fmt}.onnx"
        assert cli_main(["export", "--preset", "tiny", "--random-init", "-o", str(out), "--format", fmt]) == 0
        sess = _session(out)
        assert len(sess.get_inputs()) == inputs
        assert sess.get_modelmeta().custom_metadata_map["equipose_format"] == fmt


def test_int8_copy(tiny_cli, rng):
    model, path = tiny_cli
    q = int8_path_for(path)
    assert q.name == "m.int8.onnx" and q.is_file() and path.is_file()
    assert q.stat().st_size < 0.8 * path.stat().st_size
    onnx.checker.check_model(str(q), full_check=True)
    proto = onnx.load(str(q))
    assert {n.domain for n in proto.graph.node} <= {"", "ai.onnx"}
    assert "MatMulInteger" in {n.op_type for n in proto.graph.node}
    q_meta = {p.key: p.value for p in proto.metadata_props}
    f_meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert q_meta.pop("precision") == "int8" and f_meta.pop("precision") == "fp32"
    assert q_meta.pop("int8_source") == hashlib.sha256(path.read_bytes()).hexdigest()   # built from that very file
    assert q_meta == f_meta
    x = _cloud(rng, 2, model.num_points)
    a = _onnx_outputs(path, x)
    b = _onnx_outputs(q, x)
    assert np.abs(a[0] - b[0]).max() < 0.05                  # canonical shape within 5 % of the unit box
    R = b[1]
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-4)


def test_cli_errors(tmp_path, capsys):
    assert cli_main(["export", "--checkpoint", str(tmp_path / "missing.pt"), "-o", str(tmp_path / "x.onnx")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert cli_main(["export", "--preset", "tiny", "-o", str(tmp_path / "x.onnx")]) == 2
    assert "--random-init" in capsys.readouterr().err
    assert cli_main(["export", "--preset", "nope", "--random-init", "-o", str(tmp_path / "x.onnx")]) == 2
    assert "unknown preset" in capsys.readouterr().err
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    assert cli_main(["export", "--checkpoint", str(tmp_path / "junk.pt"), "-o", str(tmp_path / "x.onnx")]) == 2
    assert "not a readable equipose checkpoint" in capsys.readouterr().err
    assert not (tmp_path / "x.onnx").exists()


def test_api_rejects_bad_arguments(tmp_path):
    model = EquiPoseNet("tiny")
    with pytest.raises(ConfigError):
        export_model(model, tmp_path / "a.onnx", category="mug", scale=-1.0)
    with pytest.raises(ConfigError):
        export_model(model, tmp_path / "a.onnx", category="", scale=1.0)
    with pytest.raises(MetadataError):
        export_model(model, tmp_path / "a.onnx", category="mug", scale=1.0, symmetry="spherical")
    with pytest.raises(ConfigError):
        export_model(model, tmp_path / "a.onnx", category="mug", scale=1.0,
                     calibration={"rotation": np.eye(3) * 2, "translation": [0, 0, 0]})
    with pytest.raises(ConfigError):
        export_model(torch.nn.Linear(3, 3), tmp_path / "a.onnx", category="mug", scale=1.0)
    with pytest.raises(ModelFormatError):
        from equipose.export import quantize_int8
        (tmp_path / "junk.onnx").write_bytes(b"junk")
        quantize_int8(tmp_path / "junk.onnx")
    assert not (tmp_path / "a.onnx").exists()


def test_update_metadata_and_model_card(tiny_ckpt, tmp_path):
    import shutil

    from equipose.export import update_metadata
    from equipose.models import model_card
    path = tmp_path / "cup-test.onnx"
    shutil.copy(tiny_ckpt[1], path)
    metrics = {"n": 10, "rot_median_deg": 3.5, "acc_5deg": 0.7, "icp60": {"rot_median_deg": 9.0}}
    update_metadata(path, metrics=metrics)
    card = model_card(path)
    assert card["metrics"] == metrics and card["name"] == "cup-test" and card["category"] == "mug"
    assert card["mode"] == "partial" and card["preset"] == "tiny" and card["precision"] == "fp32"
    assert card["training"]["step"] == 42 and card["size_mb"] > 0
    before = path.read_bytes()
    with pytest.raises(MetadataError):                        # re-validated before anything is written
        update_metadata(path, scale=-1.0)
    assert path.read_bytes() == before
    with pytest.raises(ModelFormatError):
        update_metadata(tmp_path / "missing.onnx", metrics={})


def test_refined_calibration_round_trip(tiny_ckpt, tmp_path, rng):
    """calibrate_onnx_refined → refine_calibration metadata → PoseEstimator(refine='auto') uses k, iters, copies and
    it."""
    import shutil

    from equipose import PoseEstimator
    from equipose.export import update_metadata
    from equipose.train.evaluation.calibration import calibrate_onnx_refined
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_ckpt[1], path)
    assert PoseEstimator(path, threads=1).refine == 0                        # no refined calibration: off
    canon = _cloud(rng, 4, 300).astype(np.float64)
    cal = calibrate_onnx_refined(path, canon, k=3, iters=4)
    assert cal["k"] == 3 and cal["iters"] == 4 and cal["n"] == 4
    R = np.asarray(cal["rotation"])
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    update_metadata(path, refine_calibration=cal)
    est = PoseEstimator(path, threads=1)
    assert est.refine == 3 and est.refine_iters == 4
    np.testing.assert_allclose(est.calibration_rotation, R)
    assert est.copies == 1                                                   # calibrated with one copy
    plain = PoseEstimator(path, threads=1, refine=0)
    np.testing.assert_allclose(plain.calibration_rotation, CALIBRATION["rotation"])   # the network's own
    cal3 = calibrate_onnx_refined(path, canon, k=2, iters=3, copies=3)      # rotated copies: calibrated with them
    assert cal3["copies"] == 3
    update_metadata(path, refine_calibration=cal3)
    assert PoseEstimator(path, threads=1).copies == 3
    assert PoseEstimator(path, threads=1, refine=0).copies == 1              # the plain network runs one copy
    assert PoseEstimator(path, threads=1, copies=2).copies == 2
    assert cal3["visibility"] is None and PoseEstimator(path, threads=1).visibility is None
    calv = calibrate_onnx_refined(path, canon, k=2, iters=3, visibility=1.0)   # recorded; calibrated without it
    np.testing.assert_allclose(calv["rotation"], calibrate_onnx_refined(path, canon, k=2, iters=3)["rotation"])
    update_metadata(path, refine_calibration=calv)
    assert PoseEstimator(path, threads=1).visibility == 1.0                  # "auto": the file's (a partial model)
    assert PoseEstimator(path, threads=1, refine=0).visibility is None       # no re-scoring, nothing to rank
    assert PoseEstimator(path, threads=1, visibility=None).visibility is None
    with pytest.raises(MetadataError):
        update_metadata(path, refine_calibration={**calv, "visibility": 40.0})
    assert calv["polish"] == 0 and PoseEstimator(path, threads=1).polish == 0
    calp = calibrate_onnx_refined(path, canon, k=2, iters=3, polish=5)      # the calibration runs with the polish
    update_metadata(path, refine_calibration=calp)
    assert PoseEstimator(path, threads=1).polish == 5 and PoseEstimator(path, threads=1, refine=0).polish == 0
    assert PoseEstimator(path, threads=1, polish=0).polish == 0
    with pytest.raises(MetadataError):
        update_metadata(path, refine_calibration={**calp, "polish": -1})
    assert calp["densify"] == 0 and PoseEstimator(path, threads=1).densify == 0
    cald = calibrate_onnx_refined(path, canon, k=2, iters=3, densify=4)     # the calibration runs with the template
    update_metadata(path, refine_calibration=cald)
    assert PoseEstimator(path, threads=1).densify == 4 and PoseEstimator(path, threads=1, refine=0).densify == 0
    with pytest.raises(MetadataError):
        update_metadata(path, refine_calibration={**cald, "densify": 99})
    update_metadata(path, refine_calibration=cal3)
    before = path.read_bytes()
    with pytest.raises(MetadataError):                                       # validated before writing …
        update_metadata(path, refine_calibration={"k": 2})
    with pytest.raises(MetadataError):
        update_metadata(path, refine_calibration={**cal3, "copies": 0})
    assert path.read_bytes() == before
    proto = onnx.load(str(path))                                             # … and when a file carries it anyway
    next(p for p in proto.metadata_props if p.key == "refine_calibration").value = '{"k": 2}'
    onnx.save_model(proto, str(path))
    with pytest.raises(MetadataError):
        PoseEstimator(path, threads=1)


def test_export_checkpoint_overrides_category_and_scale(tiny_ckpt, tmp_path):
    """Deploying a network trained on unit-normalised shapes at a metric size: --category / --scale override."""
    ckpt = tmp_path / "c.pt"
    save_checkpoint(ckpt, tiny_ckpt[0], category="bottle", scale=2.0, symmetry="continuous:z", step=5)
    out = tmp_path / "can.onnx"
    assert cli_main(["export", "--checkpoint", str(ckpt), "-o", str(out), "--category", "can", "--scale", "0.25",
                     "--no-verify"]) == 0
    meta = decode_metadata(_session(out).get_modelmeta().custom_metadata_map)
    assert meta["category"] == "can" and meta["scale"] == 0.25 and meta["symmetry"] == "continuous:z"
    assert meta["training"]["trained_category"] == "bottle" and meta["training"]["trained_scale"] == 2.0
