"""The ``centre`` stage (a partial view's calibrated depth offset) and its fit (``equipose.train.evaluation.centre``)."""
import json

import numpy as np
import pytest

from equipose import PoseEstimator, errors
from equipose.runtime.stages.centre import MAX_OFFSET_M, parse_centre_calibration


def test_offset_moves_the_centre_along_the_camera_ray(tiny_model):
    """The reported centre moves by the offset, away from the camera (at the origin), on the line through it; the
    rotation stays."""
    pts = np.random.default_rng(3).normal(scale=0.04, size=(500, 3)) + [0.15, -0.05, 0.9]
    plain = PoseEstimator(tiny_model, threads=1).predict_points(pts)
    moved = PoseEstimator(tiny_model, threads=1, stages={"centre": {"offset": 0.008}}).predict_points(pts)
    ray = plain.translation / np.linalg.norm(plain.translation)
    np.testing.assert_allclose(moved.translation - plain.translation, 0.008 * ray, atol=1e-9)
    np.testing.assert_allclose(moved.rotation, plain.rotation)
    est = PoseEstimator(tiny_model, threads=1, stages={"centre": {"offset": -0.004}})
    assert est.pipeline_info[-1] == {"stage": "centre", "offset_m": -0.004}       # after the confidence
    assert "centre" not in [s["stage"] for s in PoseEstimator(tiny_model, threads=1).pipeline_info]   # no entry


@pytest.mark.parametrize("bad", ["near", True, 0.2, float("nan")])
def test_offset_option_is_checked(tiny_model, bad):
    with pytest.raises(errors.ConfigError, match="centre offset"):
        PoseEstimator(tiny_model, threads=1, stages={"centre": {"offset": bad}})


def test_centre_calibration_metadata_is_checked():
    assert parse_centre_calibration(None) is None
    assert parse_centre_calibration(json.dumps({"along_ray_m": 0.007, "date": "x"}))["along_ray_m"] == 0.007
    for bad in ('{"along": 0.01}', "not json", json.dumps({"along_ray_m": 2 * MAX_OFFSET_M})):
        with pytest.raises(errors.MetadataError, match="centre_calibration"):
            parse_centre_calibration(bad, "m.onnx")


@pytest.mark.parametrize("name", ["cup-tabletop", "mug-tabletop", "bowl-tabletop"])
def test_shipped_tabletop_models_carry_a_fitted_offset(name):
    """Fitted on rendered training views with the axis_centre stage: 2–4 mm away from the camera
    (docs/results/real/README.md, v0.48; 4–8 mm before that stage, v0.40)."""
    est = PoseEstimator(name, threads=1)
    info = est.pipeline_info[-1]
    assert info["stage"] == "centre" and 0.001 < info["offset_m"] < 0.006


def test_fit_offset_minimises_the_mean_centre_error():
    from equipose.train.evaluation.centre import fit_offset, summarize_centres
    rng = np.random.default_rng(0)
    rows = [{"view": i, "prompt": "box", "up": "none", "along": a, "across": c, "error": float(np.hypot(a, c))}
            for i, (a, c) in enumerate(zip(rng.normal(-0.008, 0.004, 400), np.abs(rng.normal(0.0, 0.006, 400))))]
    offset = fit_offset(rows)
    assert 0.0065 < offset < 0.0095                                              # undoes the 8 mm bias
    s = summarize_centres(rows, offset)["all"]
    assert s["offset_error_mean_m"] < s["error_mean_m"] and s["along_median_m"] < -0.006


def test_a_written_offset_reaches_the_file_and_its_int8_copy(tiny_model, tmp_path):
    """``update_metadata_with_int8`` (what ``--write`` calls): the fp32 file gets the entry, and the int8 copy built
    from it runs the stage too."""
    import shutil
    from equipose.export.onnx_export import update_metadata_with_int8
    from equipose.models.int8 import ensure_int8
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_model, path)
    update_metadata_with_int8(path, centre_calibration={"along_ray_m": 0.006, "fitted_on": "test"})
    assert PoseEstimator(str(path), threads=1).pipeline_info[-1] == {"stage": "centre", "offset_m": 0.006}
    int8 = ensure_int8(path)
    assert PoseEstimator(str(int8), threads=1).pipeline_info[-1] == {"stage": "centre", "offset_m": 0.006}
