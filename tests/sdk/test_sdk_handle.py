"""Mug handle: finding it on a cloud, the handle-zone visibility check, metadata, and the estimator's report."""
import shutil

import numpy as np
import pytest

from equipose.core.errors import InvalidPointsError, MetadataError
from equipose.core.handles import (HANDLE_MAX_RATIO, align_handle, clustered_count, fit_handle, handle_zone_count,
                                   handle_zone_mask, turn_about_z)


def synthetic_mug(azimuth_deg=0.0, radius=0.04, height=0.10, n=3000, handle=True, seed=0):
    """[P, 3] metres: an open cylinder with a bottom and (optionally) a C-shaped handle at ``azimuth_deg`` about +z."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(0, 2 * np.pi, n)
    z = rng.uniform(-height / 2, height / 2, n)
    side = np.c_[radius * np.cos(a), radius * np.sin(a), z]
    rb = radius * np.sqrt(rng.uniform(0, 1, n // 4))
    ab = rng.uniform(0, 2 * np.pi, n // 4)
    bottom = np.c_[rb * np.cos(ab), rb * np.sin(ab), np.full(n // 4, -height / 2)]
    parts = [side, bottom]
    if handle:                                                                  # half ring in the xz-plane, tube 5 mm
        m = n // 5
        phi = rng.uniform(-np.pi / 2, np.pi / 2, m)
        psi = rng.uniform(0, 2 * np.pi, m)
        ring_r, tube = 0.028, 0.005
        rr = ring_r + tube * np.cos(psi)
        parts.append(np.c_[radius + rr * np.cos(phi) - 0.008, tube * np.sin(psi), rr * np.sin(phi)])
    p = np.vstack(parts)
    return p @ turn_about_z(np.radians(azimuth_deg)).T


@pytest.mark.parametrize("azimuth", [0.0, 37.0, 135.0, -100.0])
def test_fit_handle_finds_the_azimuth(azimuth):
    fit = fit_handle(synthetic_mug(azimuth))
    assert fit.has_handle
    err = np.degrees(np.angle(np.exp(1j * (fit.azimuth - np.radians(azimuth)))))
    assert abs(err) < 5.0, (azimuth, np.degrees(fit.azimuth))
    aligned = align_handle(synthetic_mug(azimuth))
    assert abs(fit_handle(aligned).azimuth) < np.radians(5.0)


def test_fit_handle_without_handle_and_bad_input():
    assert not fit_handle(synthetic_mug(handle=False)).has_handle
    with pytest.raises(InvalidPointsError):
        fit_handle(np.zeros((10, 3)))
    assert issubclass(InvalidPointsError, ValueError)


def test_handle_zone_sees_the_handle_only_where_it_is():
    mug = synthetic_mug(0.0)
    canonical = synthetic_mug(0.0, n=800, seed=1)
    toward = mug[mug[:, 0] > -0.01]                                             # the half facing the handle side
    away = mug[mug[:, 0] < -0.01]                                               # seen from the back: handle hidden
    assert handle_zone_count(toward, canonical, [1, 0, 0]) > 50
    assert handle_zone_count(away, canonical, [1, 0, 0]) == 0
    turned = toward @ turn_about_z(np.radians(90.0)).T                          # pose wrong by 90° about the axis
    assert handle_zone_count(turned, canonical, [1, 0, 0]) == 0
    q = turn_about_z(np.radians(90.0))                                          # a frame with the handle along +y
    assert handle_zone_count(turned, canonical @ q.T, [0, 1, 0]) > 50
    with pytest.raises(InvalidPointsError):
        handle_zone_count(toward, canonical[:10], [1, 0, 0])


def test_a_body_wider_than_the_predicted_shape_is_not_a_handle():
    """A mug seen with its handle hidden, posed against a predicted shape 25 % too narrow (a body cut by an
    occluder): its own wall lies beyond 1.15 × the predicted radius. Bounded by the observed body, it is no handle;
    a real handle on a body of the predicted width still is."""
    canonical = synthetic_mug(0.0, radius=0.032, n=800, seed=1)                 # predicted: 25 % too narrow
    hidden = synthetic_mug(0.0, handle=False)
    front = hidden[(hidden[:, 0] > -0.01) & (hidden[:, 2] > -0.0499)]          # the wall facing +x (the table
                                                                                # hides the bottom), no handle
    assert handle_zone_mask(front, canonical, [1, 0, 0], HANDLE_MAX_RATIO).sum() > 100    # the wall reads as handle
    assert not handle_zone_mask(front, canonical, [1, 0, 0], HANDLE_MAX_RATIO, observed_body=True).any()
    mug = synthetic_mug(0.0)
    seen = mug[mug[:, 0] > -0.01]
    right = synthetic_mug(0.0, n=800, seed=1)
    both = handle_zone_mask(seen, right, [1, 0, 0], HANDLE_MAX_RATIO, observed_body=True)
    assert both.sum() > 50
    assert both.sum() >= 0.9 * handle_zone_mask(seen, right, [1, 0, 0], HANDLE_MAX_RATIO).sum()


def test_a_strip_beyond_any_handle_is_not_the_handle():
    """An occluder's edge standing 3.5 body radii off the axis outweighs a real handle unless the fit is bounded."""
    rng = np.random.default_rng(3)
    mug = synthetic_mug(0.0)
    y = rng.uniform(-0.03, 0.03, 600)
    strip = np.c_[np.full(600, -0.14), y, rng.uniform(-0.05, 0.05, 600)]     # at azimuth 180°, 0.14 m out
    cloud = np.vstack([mug, strip])
    assert abs(np.degrees(fit_handle(cloud).azimuth)) > 150.0                 # unbounded: the strip wins
    bounded = fit_handle(cloud, max_ratio=HANDLE_MAX_RATIO)
    assert bounded.has_handle and abs(np.degrees(bounded.azimuth)) < 5.0
    canonical = synthetic_mug(0.0, n=800, seed=1)
    zone = handle_zone_mask(strip @ turn_about_z(np.pi).T, canonical, [1, 0, 0])    # the strip turned onto +x
    assert zone.sum() > 500
    assert not handle_zone_mask(strip @ turn_about_z(np.pi).T, canonical, [1, 0, 0], HANDLE_MAX_RATIO).any()


def test_clustered_count_tells_a_surface_from_scattered_points():
    rng = np.random.default_rng(0)
    body = synthetic_mug(0.0, n=400, handle=False)
    patch = np.c_[rng.uniform(0.05, 0.06, 40), rng.uniform(-0.005, 0.005, 40), rng.uniform(-0.02, 0.02, 40)]
    scattered = np.c_[rng.uniform(0.05, 0.09, 8), rng.uniform(-0.04, 0.04, 8), rng.uniform(-0.05, 0.05, 8)]
    for extra, expected in ((patch, lambda c: c >= 30), (scattered, lambda c: c == 0)):
        cloud = np.vstack([body, extra])
        member = np.r_[np.zeros(len(body), bool), np.ones(len(extra), bool)]
        assert expected(clustered_count(cloud, member)), clustered_count(cloud, member)
    assert clustered_count(body, np.zeros(len(body), bool)) == 0
    with pytest.raises(InvalidPointsError):
        clustered_count(body, np.ones(3, bool))


def test_resolve_handle_turns_the_pose_to_the_seen_handle():
    from scipy.spatial.transform import Rotation
    from equipose.runtime.handle import resolve_handle
    R_true = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    t = np.array([0.01, -0.02, 0.03])
    mug = synthetic_mug(0.0, n=1500)
    seen = mug[mug[:, 1] < 0.01]                                                # a partial view, handle in profile
    pts = seen @ R_true.T + t
    wrong = R_true @ turn_about_z(np.radians(110.0))                            # axis right, azimuth wrong
    R, found, fit = resolve_handle([1, 0, 0], pts, wrong, t)
    assert found
    err = np.degrees(np.arccos(np.clip((np.trace(R.T @ R_true) - 1) / 2, -1, 1)))
    assert err < 5.0, err
    back = mug[mug[:, 0] < -0.02] @ R_true.T + t                                # handle hidden behind the body
    R2, found2, _ = resolve_handle([1, 0, 0], back, wrong, t)
    assert not found2 and np.allclose(R2, wrong)


def test_handle_metadata_round_trip():
    from equipose.core.metadata import decode_metadata, encode_metadata
    base = dict(category="mug", preset="tiny", model_config={}, num_points=256, num_canonical_points=256, scale=0.16,
                partial=True)
    meta = encode_metadata(**base, handle=(2.0, 0.0, 0.0))
    assert np.allclose(decode_metadata(meta)["handle"], [1.0, 0.0, 0.0])
    assert decode_metadata(encode_metadata(**base))["handle"] is None
    for bad in ('{"direction": [0, 0, 1]}', '{"direction": [0, 0, 0]}', '{"dir": [1, 0, 0]}', "[1, 0"):
        with pytest.raises(MetadataError):
            decode_metadata(dict(meta, handle=bad))


def test_estimator_reports_the_handle(tiny_model, tmp_path):
    pytest.importorskip("onnx")
    from equipose import PoseEstimator
    from equipose.export.onnx_export import update_metadata
    path = tmp_path / "mug_handle.onnx"
    shutil.copy(tiny_model, path)
    update_metadata(path, handle={"direction": [1.0, 0.0, 0.0]})
    est = PoseEstimator(path, threads=1)
    assert np.allclose(est.handle, [1, 0, 0])
    mug = synthetic_mug(30.0) + np.array([0.0, 0.0, 0.7])
    res = est.predict_points(mug[mug[:, 2] < 0.7 + 0.02])
    assert res.handle_visible in (True, False)                                  # random weights: the check, not the pose
    d = res.to_dict()
    assert d["handle_visible"] == res.handle_visible and len(d["handle_direction"]) == 3
    assert np.allclose(res.handle_direction, res.rotation @ [1, 0, 0])
    if not res.handle_visible:
        assert res.ambiguous
    res.set_pose(np.eye(3), res.translation)                                    # smoothing keeps it consistent
    assert np.allclose(res.handle_direction, [1, 0, 0])
    img = res.plot(np.zeros((480, 640), np.uint16) + 700, np.array([[525, 0, 320], [0, 525, 240], [0, 0, 1.0]]))
    assert img.shape == (480, 640, 3)
    plain = PoseEstimator(tiny_model, threads=1).predict_points(mug)
    assert plain.handle_visible is None and "handle_visible" not in plain.to_dict()


def test_refine_calibration_ignores_the_stages(tiny_model, tmp_path):
    """The ICP re-scoring calibration works in the learned frame: the handle / cylinder stages must not touch it."""
    pytest.importorskip("onnx")
    from equipose.export.onnx_export import update_metadata
    from equipose.train.evaluation.calibration import calibrate_onnx_refined
    staged = tmp_path / "staged.onnx"
    shutil.copy(tiny_model, staged)
    update_metadata(staged, handle={"direction": [1.0, 0.0, 0.0]}, shape_prior="cylinder")
    pts = np.stack([synthetic_mug(a, n=600, seed=k)[:, [0, 1, 2]] / 0.25 for k, a in enumerate((0, 50, 100, 150))])
    a = calibrate_onnx_refined(tiny_model, pts, k=2, iters=2)
    b = calibrate_onnx_refined(staged, pts, k=2, iters=2)
    assert np.allclose(a["rotation"], b["rotation"]) and np.allclose(a["translation"], b["translation"])
