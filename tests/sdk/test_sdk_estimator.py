"""PoseEstimator end to end on a tiny random-weight model: results, batch, calibration, and the bad-input battery."""
import json

import numpy as np
import pytest

from conftest import K_VGA, sphere_scene
from equipose import errors
from equipose.runtime.result import FrameError

CENTRE = np.array([0.0, 0.0, 0.8])


@pytest.fixture(scope="module")
def scene():
    return sphere_scene(CENTRE, 0.05)


def test_predict_returns_a_metric_pose_with_timings(estimator, scene):
    depth, hit = scene
    r = estimator.predict(depth, K_VGA, box=(250, 170, 140, 140))
    np.testing.assert_allclose(r.rotation @ r.rotation.T, np.eye(3), atol=1e-5)
    assert r.translation.shape == (3,) and np.all(np.isfinite(r.translation))
    q = r.quaternion
    assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-9
    assert 0.0 <= r.confidence <= 1.0 and isinstance(r.ambiguous, bool)
    assert r.canonical_shape.shape == (estimator.num_canonical_points, 3)
    # the canonical shape in the camera frame is the object-frame shape posed by (R, t)
    np.testing.assert_allclose(r.canonical_shape, r.canonical_shape_object @ r.rotation.T + r.translation, atol=1e-9)
    assert set(r.timings) >= {"crop", "fps", "inference", "selection", "total"}
    d = json.loads(json.dumps(r.to_dict()))
    assert d["category"] == "mug" and d["random_init"] is True and len(d["quaternion_wxyz"]) == 4
    img = r.plot(depth, K_VGA)
    assert img.shape == (480, 640, 3) and img.dtype == np.uint8


def test_batch_equals_single_and_translation_follows_the_object(estimator, scene):
    depth, hit = scene
    single = estimator.predict(depth, K_VGA, mask=hit)
    batch = estimator.predict_batch(depth, K_VGA, masks=[hit, hit])
    assert len(batch) == 2 and batch[0].timings["batch"] == 2
    for b in batch:
        np.testing.assert_allclose(b.rotation, single.rotation, atol=1e-4)
        np.testing.assert_allclose(b.translation, single.translation, atol=1e-4)
    # translation equivariance of the pipeline: shifting the points shifts t by the same amount, R unchanged
    pts = estimator.crop(depth, K_VGA, mask=hit).points
    v = np.array([0.1, -0.05, 0.3])
    a, b = estimator.predict_points(pts), estimator.predict_points(pts + v)
    np.testing.assert_allclose(b.translation - a.translation, v, atol=1e-4)
    np.testing.assert_allclose(b.rotation, a.rotation, atol=1e-4)


def test_predict_points_matches_predict(estimator, scene):
    depth, hit = scene
    pts = estimator.crop(depth, K_VGA, mask=hit).points
    a = estimator.predict_points(pts)
    b = estimator.predict(depth, K_VGA, mask=hit)
    np.testing.assert_allclose(a.rotation, b.rotation, atol=1e-6)
    np.testing.assert_allclose(a.translation, b.translation, atol=1e-6)


def test_batch_reports_per_object_errors(estimator, scene):
    depth, hit = scene
    out = estimator.predict_batch(depth, K_VGA, boxes=[(250, 170, 140, 140), (2000, 10, 5, 5)], return_errors=True)
    assert hasattr(out[0], "rotation")
    assert isinstance(out[1], FrameError) and out[1].error == "RegionError" and out[1].object_id == 1


def test_calibration_from_metadata_is_applied(tiny_model, scene):
    from scipy.spatial.transform import Rotation

    from equipose import PoseEstimator
    depth, hit = scene
    raw = PoseEstimator(tiny_model, threads=1)
    cal = PoseEstimator(tiny_model, threads=1)
    dR = Rotation.from_euler("zyx", [30, -20, 75], degrees=True).as_matrix()
    dt = np.array([0.1, -0.05, 0.2])                                           # model units
    cal.calibration_rotation, cal.calibration_translation = dR, dt
    a, b = raw.predict(depth, K_VGA, mask=hit), cal.predict(depth, K_VGA, mask=hit)
    assert a.hypothesis_index == b.hypothesis_index
    np.testing.assert_allclose(b.rotation, a.rotation @ dR.T, atol=1e-9)
    np.testing.assert_allclose(b.translation, a.translation - b.rotation @ dt * raw.scale, atol=1e-9)
    np.testing.assert_allclose(b.canonical_shape, a.canonical_shape, atol=1e-9)  # same posed reconstruction


# ----------------------------------------------------------------------------------------------------------------------
# The bad-input battery (issue 5): each case raises its own typed error (a ValueError), never a raw traceback.

def _bad_cases(scene):
    depth, hit = scene
    few = np.zeros_like(hit)
    few[240, 320:330] = True                                                    # 10 pixels
    uint8_colour = np.stack([depth.astype(np.uint8)] * 3, -1)                   # what cv2.imread(path) returns
    return {
        "empty depth": (dict(depth=np.zeros((0, 0), np.uint16)), errors.EmptyDepthError),
        "all-invalid depth": (dict(depth=np.zeros((480, 640), np.uint16)), errors.EmptyDepthError),
        "all-NaN float depth": (dict(depth=np.full((480, 640), np.nan, np.float32), depth_unit="m"),
                                errors.EmptyDepthError),
        "fewer than 64 points": (dict(mask=few), errors.TooFewPointsError),
        "uint8 depth": (dict(depth=depth.astype(np.uint8)), errors.DepthDtypeError),
        "uint8 colour from cv2.imread": (dict(depth=uint8_colour), errors.DepthDtypeError),
        "K not 3x3": (dict(K=np.eye(4)), errors.IntrinsicsError),
        "K flat list": (dict(K=K_VGA.ravel().tolist()), errors.IntrinsicsError),
        "K for another image size": (dict(K=np.array([[525, 0, 959.5], [0, 525, 539.5], [0, 0, 1.0]])),
                                     errors.IntrinsicsError),
        "image_size with another aspect": (dict(image_size=(1280, 720)), errors.IntrinsicsError),
        "metres declared as mm": (dict(depth=depth.astype(np.float32) / 1000, depth_unit="mm"), errors.DepthUnitError),
        "mm declared as metres": (dict(depth_unit="m"), errors.DepthUnitError),
        "unknown unit": (dict(depth_unit="inch"), errors.DepthUnitError),
        "box outside the image": (dict(box=(700, 500, 50, 50)), errors.RegionError),
        "box with negative size": (dict(box=(100, 100, -5, 20)), errors.RegionError),
        "empty mask": (dict(mask=np.zeros_like(hit)), errors.RegionError),
        "mask of another size": (dict(mask=np.ones((240, 320), bool)), errors.RegionError),
    }


@pytest.mark.parametrize("case", ["empty depth", "all-invalid depth", "all-NaN float depth", "fewer than 64 points",
                                  "uint8 depth", "uint8 colour from cv2.imread", "K not 3x3", "K flat list",
                                  "K for another image size", "image_size with another aspect", "metres declared as mm",
                                  "mm declared as metres", "unknown unit", "box outside the image",
                                  "box with negative size", "empty mask", "mask of another size"])
def test_bad_frame_input_raises_its_typed_error(estimator, scene, case):
    kwargs, err = _bad_cases(scene)[case]
    args = dict(depth=scene[0], K=K_VGA, box=None, mask=scene[1] if "box" not in kwargs else None)
    args.update(kwargs)
    with pytest.raises(err) as info:
        estimator.predict(**args)
    assert isinstance(info.value, ValueError) and len(str(info.value)) > 30     # says what to do


@pytest.mark.parametrize("bad", ["nan", "inf", "shape", "few"])
def test_bad_points_raise_typed_errors(estimator, bad):
    pts = np.random.default_rng(0).normal(scale=0.05, size=(500, 3)) + [0, 0, 0.8]
    if bad == "nan":
        pts[7, 1] = np.nan
    elif bad == "inf":
        pts[3, 2] = np.inf
    elif bad == "shape":
        pts = pts[:, :2]
    else:
        pts = pts[:20]
    err = errors.TooFewPointsError if bad == "few" else errors.InvalidPointsError
    with pytest.raises(err):
        estimator.predict_points(pts)


def test_model_file_errors(tmp_path, tiny_model):
    import onnx
    from onnx import TensorProto, helper

    from equipose import PoseEstimator
    with pytest.raises(errors.ModelFormatError, match="does not exist"):
        PoseEstimator(tmp_path / "missing.onnx")
    junk = tmp_path / "junk.onnx"
    junk.write_text("this is not a protobuf")
    with pytest.raises(errors.ModelFormatError, match="not a loadable ONNX model"):
        PoseEstimator(junk)
    # a valid ONNX model that is not an equipose model
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 3])
    y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, 3])
    plain = helper.make_model(helper.make_graph([helper.make_node("Relu", ["x"], ["y"])], "g", [x], [y]),
                              opset_imports=[helper.make_opsetid("", 17)])
    plain.ir_version = 8
    onnx.save(plain, tmp_path / "plain.onnx")
    with pytest.raises(errors.MetadataError, match="not an equipose model"):
        PoseEstimator(tmp_path / "plain.onnx")

    def with_props(name, change):
        m = onnx.load(str(tiny_model))
        props = {p.key: p.value for p in m.metadata_props}
        change(props)
        del m.metadata_props[:]
        for k, v in props.items():
            m.metadata_props.add(key=k, value=v)
        path = tmp_path / name
        onnx.save(m, str(path))
        return path

    with pytest.raises(errors.ModelVersionError, match="format 99"):
        PoseEstimator(with_props("v99.onnx", lambda p: p.update(equipose_format="99")))
    with pytest.raises(errors.MetadataError, match="scale"):
        PoseEstimator(with_props("noscale.onnx", lambda p: p.pop("scale")))
    with pytest.raises(errors.MetadataError, match="symmetry"):
        PoseEstimator(with_props("badsym.onnx", lambda p: p.update(symmetry="discrete:weird")))
    with pytest.raises(errors.ConfigError):
        PoseEstimator(tiny_model, threads=-1)


def test_cli_reports_bad_input_without_a_traceback(tmp_path, capsys):
    from equipose.cli import main
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"\x00\x01garbage")
    assert main(["predict", "--model", str(junk), "--source", str(tmp_path), "--auto"]) == 2
    err = capsys.readouterr().err
    assert "error:" in err and "Traceback" not in err
    assert main(["predict", "--source", str(tmp_path / "nope"), "--auto"]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_batch_arguments_and_runtime_failures_are_typed(estimator, scene, monkeypatch):
    depth, hit = scene
    with pytest.raises(errors.RegionError):
        estimator.predict_batch(depth, K_VGA, boxes=5)
    with pytest.raises(errors.RegionError):
        estimator.predict_batch(depth, K_VGA, boxes=[(250, 170, 140, 140)], masks=[hit, hit])

    class Broken:
        def run(self, *a, **k):
            raise RuntimeError("[ONNXRuntimeError] : 6 : RUNTIME_EXCEPTION : simulated")
    monkeypatch.setattr(estimator, "session", Broken())
    with pytest.raises(errors.ModelFormatError, match="could not run"):
        estimator.predict(depth, K_VGA, mask=hit)


def test_symmetric_category_reports_axis_and_canonical_rotation(tiny_model, scene):
    from equipose import PoseEstimator
    from equipose.runtime.hypotheses import canonicalise_rotation
    depth, hit = scene
    est = PoseEstimator(tiny_model, threads=1)
    est.symmetry = "continuous:z"                                              # as if the metadata said so
    r = est.predict(depth, K_VGA, mask=hit)
    np.testing.assert_allclose(r.symmetry_axis, r.rotation[:, 2])
    np.testing.assert_allclose(r.rotation_canonical[:, 2], r.rotation[:, 2], atol=1e-12)
    np.testing.assert_allclose(r.rotation_canonical, canonicalise_rotation(r.rotation, "continuous:z"))
    assert r.to_dict()["symmetry"] == "continuous:z" and len(r.to_dict()["symmetry_axis"]) == 3
    plain = PoseEstimator(tiny_model, threads=1).predict(depth, K_VGA, mask=hit)
    assert plain.symmetry_axis is None and np.allclose(plain.rotation_canonical, plain.rotation)


def test_shipped_model_by_name():
    from equipose import PoseEstimator
    from equipose.errors import ModelFormatError
    from equipose.models import demo_model_path, model_names, resolve_model
    assert {"cup-tabletop", "cup-tabletop.int8", "airplane-complete"} <= set(model_names())
    assert resolve_model("cup-tabletop") == demo_model_path() == resolve_model("CUP_tabletop.onnx")
    est = PoseEstimator("cup-tabletop", threads=1)
    assert est.path == demo_model_path() and est.category == "cup" and not est.random_init
    assert est.metadata["metrics"]["n"] > 0 and "icp60" in est.metadata["metrics"]          # its own test metrics
    assert PoseEstimator("cup-tabletop.int8", threads=1).metadata["precision"] == "int8"
    with pytest.raises(ModelFormatError, match="shipped"):
        PoseEstimator("no-such-model")


def test_adaptive_threads_run_single_objects_on_one_thread_with_the_same_outputs(tiny_model, scene):
    from equipose import PoseEstimator
    depth, hit = scene
    est = PoseEstimator(tiny_model, threads=2)                                  # tiny: a light model
    assert est.single_thread and est._single_sessions
    fixed = PoseEstimator(tiny_model, threads=2, adaptive_threads=False)
    assert not fixed.single_thread and not PoseEstimator(tiny_model, threads=1).single_thread
    assert est._single_sessions[0].get_session_options().intra_op_num_threads == 1
    a = est.predict(depth, K_VGA, mask=hit)
    b = fixed.predict(depth, K_VGA, mask=hit)
    np.testing.assert_allclose(a.rotation, b.rotation, atol=1e-5)
    assert a.hypothesis_index == b.hypothesis_index
    assert len(est._single_sessions) == 2                                       # one per thread of the budget
    assert all(s.get_session_options().intra_op_num_threads == 1 for s in est._single_sessions)
    two = est.predict_batch(depth, K_VGA, masks=[hit, hit])                     # a batch: two parts side by side
    np.testing.assert_allclose(two[1].rotation, a.rotation, atol=1e-5)
    x = np.random.default_rng(3).normal(size=(5, est.num_points, 3)).astype(np.float32) * 0.3
    split, whole = est.run_model(x), fixed.run_model(x)                         # parts of 3 + 2 rows, in order
    for k in whole:
        np.testing.assert_allclose(split[k], whole[k], atol=1e-5)
