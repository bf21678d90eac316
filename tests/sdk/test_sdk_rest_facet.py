"""The rest-facet stage (``equipose.runtime.rest_facet``): "up" of a complete cloud from the hull face it stands on."""
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors
from equipose.runtime.rest_facet import rest_facet_up


def _car(rng):
    """A car-like cloud, +z up: a body box above four wheel discs whose lowest points touch z = 0."""
    body = np.c_[rng.uniform(-1, 1, 800), rng.uniform(-0.45, 0.45, 800), rng.uniform(0.15, 0.6, 800)]
    wheels = []
    for cx in (-0.7, 0.7):
        for cy in (-0.45, 0.45):
            a = rng.uniform(0, 2 * np.pi, 60)
            wheels.append(np.c_[cx + 0.15 * np.cos(a), np.full(60, cy), 0.15 + 0.15 * np.sin(a)])
    return np.vstack([body] + wheels)


def _deg(a, b):
    return np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0)))


def test_rest_facet_finds_the_wheel_plane(rng):
    R = Rotation.from_euler("zyx", [30, 12, -7], degrees=True).as_matrix()
    pts = _car(rng) @ R.T
    guess = Rotation.from_euler("x", 9, degrees=True).apply(R[:, 2])          # the network's up, 9° off
    up = rest_facet_up(pts, guess)
    assert _deg(up, R[:, 2]) < 0.5


def test_rest_facet_none_when_nothing_fits(rng):
    tetra = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, -0.3], [-0.5, 0.8, -0.3], [-0.5, -0.8, -0.3]])
    assert _deg(rest_facet_up(tetra, [0.0, 0.1, 1.0]), [0.0, 0.0, 1.0]) < 1e-6   # stands on its base
    assert rest_facet_up(tetra, [0.0, 0.0, -1.0], tolerance_deg=30.0) is None   # no face down-facing for "up" = −z
    flat = np.c_[rng.normal(size=(100, 2)), np.zeros(100)]
    assert rest_facet_up(flat, [0.0, 0.0, 1.0]) is None                          # degenerate hull


def test_model_with_rest_facet_metadata(tiny_model, tmp_path, rng):
    from equipose.export.onnx_export import update_metadata
    path = tmp_path / "rest.onnx"
    shutil.copy(tiny_model, path)
    update_metadata(path, rest_facet={"tolerance_deg": 89.0})                  # the random model's up is a guess
    r = PoseEstimator(path).predict_points(_car(rng) * 0.05 + [0.0, 0.0, 0.7])
    assert r.up_source == "rest_facet" and r.to_dict()["up_source"] == "rest_facet"
    np.testing.assert_allclose(r.rotation[:, 2], r.up, atol=1e-9)
    assert PoseEstimator(tiny_model).predict_points(_car(rng) * 0.05 + [0.0, 0.0, 0.7]).up_source is None
    for bad in ({"tolerance_deg": 0}, {"tolerance_deg": 120}, {"tol": 20}):
        with pytest.raises(errors.MetadataError, match="rest_facet"):
            update_metadata(path, rest_facet=bad)
