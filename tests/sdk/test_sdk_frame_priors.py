"""Frame priors of complete-shape models (``equipose.runtime.frame_priors``): the pose turned onto the cloud's mirror
plane and footprint rectangle, and the export-time choice of the steps (``equipose.export.frame_priors``)."""
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors
from equipose.runtime.frame_priors import apply_frame_priors, footprint_yaw, mirror_plane


def _sofa(rng, n=1500):
    """A sofa-like cloud in its category frame: mirror plane x = 0, footprint 1.6 × 0.8 along x / y, back at +y; points
    on the boxes' surfaces (a mirror plane shows in a surface, not in a filled volume)."""
    def box(lo, hi, k):
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        p = rng.uniform(lo, hi, size=(k, 3))
        ext = hi - lo
        area = np.array([ext[1] * ext[2], ext[0] * ext[2], ext[0] * ext[1]])   # faces normal to x, y, z
        axis = rng.choice(3, size=k, p=area / area.sum())
        p[np.arange(k), axis] = np.where(rng.random(k) < 0.5, lo[axis], hi[axis])
        return p
    parts = [box([-0.8, -0.4, 0.0], [0.8, 0.4, 0.25], n // 2),                # seat
             box([-0.8, 0.25, 0.25], [0.8, 0.4, 0.7], n // 4),                # back
             box([-0.8, -0.4, 0.25], [-0.65, 0.25, 0.45], n // 8),            # arms
             box([0.65, -0.4, 0.25], [0.8, 0.25, 0.45], n // 8)]
    pts = np.vstack(parts)
    return pts - pts.mean(0)


def _deg(A, B):
    return float(np.degrees(np.arccos(np.clip((np.trace(A.T @ B) - 1.0) / 2.0, -1.0, 1.0))))


@pytest.fixture
def posed(rng):
    R = Rotation.from_euler("zyx", [40, -25, 15], degrees=True).as_matrix()   # category → camera
    return R, _sofa(rng) @ R.T


def test_footprint_turns_onto_the_rectangle(posed):
    R, pts = posed
    off = R @ Rotation.from_euler("z", 7, degrees=True).as_matrix()           # 7° off about the object's up
    fixed, turn = footprint_yaw(pts, off)
    assert abs(abs(turn) - 7.0) < 0.5 and _deg(fixed, R) < 0.5
    far = R @ Rotation.from_euler("z", 30, degrees=True).as_matrix()          # nearest side 30° away: left alone
    same, turn = footprint_yaw(pts, far, max_deg=20.0)
    assert turn is None and np.array_equal(same, far)


def test_mirror_plane_of_a_tilted_pose(posed):
    R, pts = posed
    off = R @ Rotation.from_euler("y", 6, degrees=True).as_matrix()           # the mirror normal (x) tilted 6°
    n, d, res = mirror_plane(pts, off[:, 0])
    assert np.degrees(np.arccos(min(1.0, n @ R[:, 0]))) < 1.0 and abs(d) < 0.02
    turned, steps = apply_frame_priors(pts, off, {"steps": ["mirror"], "mirror_axis": "x", "max_deg": 20.0})
    assert _deg(turned, R) < 1.0 and 5.0 < steps["mirror"] < 7.0


def test_both_steps_and_the_kept_up(posed):
    R, pts = posed
    off = R @ Rotation.from_euler("zy", [6, 4], degrees=True).as_matrix()
    spec = {"steps": ["mirror", "footprint"], "mirror_axis": "x", "max_deg": 20.0}
    turned, steps = apply_frame_priors(pts, off, spec)
    assert _deg(turned, R) < 1.0 and set(steps) == {"mirror", "footprint"}
    np.testing.assert_allclose(turned @ turned.T, np.eye(3), atol=1e-9)
    kept, _ = apply_frame_priors(pts, off, {**spec, "steps": ["mirror"]}, keep_up=off[:, 2])
    np.testing.assert_allclose(kept[:, 2], off[:, 2], atol=1e-9)                # the caller's up is held exactly


def test_rest_step_stands_the_pose_on_its_base(posed):
    R, pts = posed
    off = R @ Rotation.from_euler("x", 8, degrees=True).as_matrix()           # up tilted 8°
    turned, steps = apply_frame_priors(pts, off, {"steps": ["rest"], "max_deg": 20.0})
    assert np.degrees(np.arccos(min(1.0, turned[:, 2] @ R[:, 2]))) < 0.5 and 7.0 < steps["rest"] < 9.0


def test_bad_inputs():
    with pytest.raises(errors.InvalidPointsError):
        footprint_yaw(np.zeros((3, 3)), np.eye(3))
    with pytest.raises(errors.InvalidPointsError):
        apply_frame_priors(np.full((50, 3), np.nan), np.eye(3), {"steps": ["footprint"]})
    for spec in ({}, {"steps": ["spin"]}, {"steps": ["mirror"]}, None):
        with pytest.raises(errors.ConfigError, match="frame priors"):
            apply_frame_priors(np.random.default_rng(0).normal(size=(50, 3)), np.eye(3), spec)


def test_model_metadata(tiny_model, tmp_path, rng):
    from equipose.export.onnx_export import update_metadata
    path = tmp_path / "fp.onnx"
    shutil.copy(tiny_model, path)
    pts = _sofa(rng) * 0.05 + [0.0, 0.0, 0.7]
    assert PoseEstimator(path).predict_points(pts).frame_priors is None
    update_metadata(path, frame_priors={"steps": ["footprint", "mirror"], "mirror_axis": "x", "max_deg": 45.0})
    r = PoseEstimator(path).predict_points(pts)
    assert set(r.frame_priors) == {"footprint", "mirror"} and "frame_priors" in r.to_dict()
    for bad in ({"steps": []}, {"steps": ["spin"]}, {"steps": ["mirror"]}, {"steps": ["mirror"], "mirror_axis": "w"},
                {"steps": ["footprint"], "max_deg": 0}, {"step": ["footprint"]}):
        with pytest.raises(errors.MetadataError, match="frame_priors"):
            update_metadata(path, frame_priors=bad)
    update_metadata(path, frame_priors="")                                      # cleared
    assert PoseEstimator(path).metadata["frame_priors"] is None


def test_choice_of_steps():
    from equipose.export.frame_priors import choose_frame_priors
    from equipose.runtime.frame_priors import parse_steps
    assert parse_steps("none", 20.0) is None and parse_steps("") is None
    assert parse_steps("rest,footprint")["steps"] == ["rest", "footprint"]
    assert parse_steps("footprint,mirror:y", 15.0) == {"steps": ["footprint", "mirror"], "mirror_axis": "y",
                                                       "max_deg": 15.0}
    for bad in ("mirror", "mirror:w", "spin", "footprint:x"):
        with pytest.raises(errors.ConfigError):
            parse_steps(bad, 20.0)
    rows = [{"steps": "none", "acc_5deg": 0.6, "median_deg": 3.0}, {"steps": "footprint", "acc_5deg": 0.7,
                                                                     "median_deg": 2.0},
            {"steps": "mirror:x", "acc_5deg": 0.7, "median_deg": 1.5}]
    assert choose_frame_priors(rows) == "mirror:x"
    assert choose_frame_priors([rows[0], {"steps": "footprint", "acc_5deg": 0.6, "median_deg": 2.99}]) == "none"


def test_stage_options_thin_the_cloud_and_set_the_mirror_iterations(tiny_model, tmp_path, rng):
    from equipose.export.onnx_export import update_metadata
    from equipose.runtime.stage import ObjectState
    path = tmp_path / "fp.onnx"
    shutil.copy(tiny_model, path)
    update_metadata(path, frame_priors={"steps": ["mirror"], "mirror_axis": "x", "max_deg": 45.0})
    est = PoseEstimator(path, stages={"frame_priors": {"points": 300, "mirror_iters": 4, "mirror_coarse": 2}})
    assert est.pipeline.get("frame_priors").describe() == {"steps": ["mirror"], "points": 300, "mirror_iters": 4,
                                                           "mirror_coarse": 2}
    pts = _sofa(rng) * 0.05 + [0.0, 0.0, 0.7]                                  # [P, 3] m
    from equipose.preprocess import prepare_points
    prep = prepare_points(pts, est.num_points, est.scale)
    state = ObjectState(prep=prep, R=np.zeros((0, 3, 3)), t=np.zeros((0, 3)), scores=np.zeros(0),
                        canonical=np.zeros((4, 3)), template=np.zeros((4, 3)), symmetry="")
    cloud = state.cloud_points("cloud")
    thin = state.cloud_points(300)                                             # a regular stride of the crop
    step = -(-len(cloud) // 300)
    assert len(cloud) > 300 and len(thin) <= 300 and np.array_equal(thin, cloud[::step])
    assert state.cloud_points(len(cloud)) is cloud and state.cloud_points("input") is prep.model_points
    assert est.predict_points(pts).frame_priors is not None
    for bad in ({"points": 8}, {"points": "all"}, {"points": True}, {"mirror_iters": 0}, {"mirror_iters": 2.5},
                {"mirror_coarse": 0}, {"mirror_coarse": "fine"}):
        with pytest.raises(errors.ConfigError, match="frame_priors"):
            PoseEstimator(path, stages={"frame_priors": bad})


def test_mirror_iterations_are_the_fit_s_iterations(rng):
    from equipose.runtime.frame_priors import MIRROR_ITERS, mirror_plane
    pts = _sofa(rng)
    spec = {"steps": ["mirror"], "mirror_axis": "x", "max_deg": 45.0}
    tilt = np.array([[np.cos(0.2), -np.sin(0.2), 0.0], [np.sin(0.2), np.cos(0.2), 0.0], [0.0, 0.0, 1.0]])
    R_default, _ = apply_frame_priors(pts, tilt, spec)
    R_full, _ = apply_frame_priors(pts, tilt, spec, mirror_iters=MIRROR_ITERS)
    R_one, _ = apply_frame_priors(pts, tilt, spec, mirror_iters=1)
    assert np.array_equal(R_default, R_full)
    n_one = mirror_plane(pts, tilt[:, 0], 45.0, iters=1)[0]
    assert np.allclose(R_one[:, 0], n_one, atol=1e-9)


def test_mirror_plane_coarse_to_fine(rng, posed):
    from equipose.runtime.frame_priors import MIRROR_FINE
    R, pts = posed
    off = R @ Rotation.from_euler("y", 6, degrees=True).as_matrix()           # the mirror normal (x) tilted 6°
    n_whole, d_whole, r_whole = mirror_plane(pts, off[:, 0])                  # every iteration on every point
    n, d, r = mirror_plane(pts, off[:, 0], coarse=3)                           # coarse to fine
    assert not np.array_equal(n, n_whole)                                      # the early iterations differ ...
    assert np.degrees(np.arccos(min(1.0, n @ n_whole))) < 0.3 and abs(d - d_whole) < 0.005   # ... the plane does not
    assert np.degrees(np.arccos(min(1.0, n @ R[:, 0]))) < 1.0
    few = mirror_plane(pts, off[:, 0], iters=MIRROR_FINE, coarse=3)            # no early iterations: coarse is moot
    assert np.array_equal(few[0], mirror_plane(pts, off[:, 0], iters=MIRROR_FINE)[0])
    for bad in (0, 1.5, True):
        with pytest.raises(errors.ConfigError, match="coarse"):
            mirror_plane(pts, off[:, 0], coarse=bad)


def test_mirror_plane_in_parts_equals_one_part(rng):
    from equipose.core.parallel import kernel_workers
    pts = _sofa(rng)
    tilt = np.array([[np.cos(0.2), -np.sin(0.2), 0.0], [np.sin(0.2), np.cos(0.2), 0.0], [0.0, 0.0, 1.0]])
    with kernel_workers(1):
        n1, d1, r1 = mirror_plane(pts, tilt[:, 0], 45.0)
    for parts in (2, 3):                                  # the reflect-and-pair pass split over threads
        with kernel_workers(parts):
            n, d, r = mirror_plane(pts, tilt[:, 0], 45.0)
        assert np.array_equal(n, n1) and d == d1 and r == r1
    assert not np.allclose(n1, tilt[:, 0], atol=1e-3)     # the fit moved: the iterations ran
