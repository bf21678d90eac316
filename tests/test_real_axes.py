"""``equipose.eval.realdata`` (table plane, object grouping, axis folding, PCA axis) and ``equipose.eval.real_axes``.

Convention: camera frame OpenCV (x right, y down, z forward), metres; angles in degrees.
"""
import json
import pathlib

import numpy as np
import pytest

from equipose.errors import InvalidPointsError, SourceError, TooFewPointsError
from equipose.eval.realdata import (LabelledScene, axis_table_angle, fit_plane, group_objects, load_labelled_scene,
                               orient_towards_camera, principal_axis, random_axis_fraction_within,
                               random_axis_summary, summarize_deviations, table_plane)

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _angle(u, v):
    return np.degrees(np.arccos(min(1.0, abs(float(np.dot(u, v))) / (np.linalg.norm(u) * np.linalg.norm(v)))))


def _plane_points(normal, point, n, rng, noise=0.002, extent=0.4):
    """n points on the plane through ``point`` with unit ``normal`` (Gaussian noise along the normal)."""
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.cross(normal, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    ab = rng.uniform(-extent, extent, size=(n, 2))
    return np.asarray(point) + ab[:, :1] * e1 + ab[:, 1:] * e2 + rng.normal(0, noise, (n, 1)) * normal


def test_fit_plane_recovers_normal_despite_outliers():
    rng = np.random.default_rng(1)
    n_true = np.array([0.0, -0.82, -0.57]); n_true /= np.linalg.norm(n_true)
    c_true = np.array([0.0, 0.2, 1.1])
    table = _plane_points(n_true, c_true, 4000, rng)
    outliers = c_true + rng.uniform(-0.3, 0.3, size=(2000, 3))                 # 33 % clutter
    pts = np.vstack([table, outliers])
    plane = fit_plane(pts, threshold=0.01, seed=0)
    assert _angle(plane.normal, n_true) < 0.5
    assert abs(np.linalg.norm(plane.normal) - 1) < 1e-9
    assert abs(abs(plane.offset) - abs(n_true @ c_true)) < 0.003
    assert plane.inliers[:4000].mean() > 0.99                                   # the table is kept ...
    assert plane.inliers[4000:].mean() < 0.1                                    # ... the clutter mostly not
    assert plane.rms < 0.004
    # a plain least-squares fit of everything is visibly worse: the RANSAC stage matters
    c = pts.mean(0)
    n_ls = np.linalg.svd(pts - c)[2][2]
    assert _angle(n_ls, n_true) > 2 * _angle(plane.normal, n_true)


def test_fit_plane_rejects_bad_input():
    with pytest.raises(InvalidPointsError):
        fit_plane(np.array([[0.0, 0.0, np.nan], [1.0, 0, 1], [0, 1, 1], [1, 1, 1]]))
    with pytest.raises(TooFewPointsError):
        fit_plane(np.zeros((2, 3)))
    with pytest.raises(InvalidPointsError):
        fit_plane(np.zeros((5, 2)))
    with pytest.raises(InvalidPointsError):                                     # collinear: no plane
        fit_plane(np.outer(np.linspace(0, 1, 50), [1.0, 2.0, 3.0]))


def test_orient_towards_camera_and_table_plane_on_a_label_image():
    n = np.array([0.0, 0.8, 0.6])                                               # points away from the camera
    assert np.allclose(orient_towards_camera(n, [0.0, 0.3, 1.0]), -n)
    assert np.allclose(orient_towards_camera(-n, [0.0, 0.3, 1.0]), -n)
    rng = np.random.default_rng(2)
    n_up = np.array([0.0, -0.8, -0.6])                                          # "up" for a camera looking down
    pts = _plane_points(n_up, [0.0, 0.25, 1.0], 60 * 80, rng).reshape(60, 80, 3)
    label = np.ones((60, 80), int)
    label[20:30, 30:40] = 20                                                    # an object: not table
    pts[20:30, 30:40] += 0.2
    label[:5] = 0
    pts[:5] = np.nan                                                            # invalid rows
    for seed in range(4):                                                       # whatever sign RANSAC finds
        plane = table_plane(pts, label, seed=seed)
        assert plane.normal @ -plane.centroid > 0
        assert plane.normal @ n_up > 0.9998                                     # < ~1°
        assert plane.inliers.sum() == 55 * 80 - 100                             # valid rows minus the object
        assert abs(plane.normal @ plane.centroid - plane.offset) < 1e-9
    with pytest.raises(TooFewPointsError):
        table_plane(pts, np.zeros_like(label))


def test_axis_folding_and_deviation():
    up = np.array([0.0, -1.0, 0.0])
    r = axis_table_angle([0, 1, 0], up)                                         # sign flip: still upright
    assert r.angle == pytest.approx(0.0, abs=1e-6) and r.deviation == pytest.approx(0.0, abs=1e-6)
    assert r.pose == "upright"
    r = axis_table_angle([3.0, 0, 0], up)                                       # lying, any length
    assert r.angle == pytest.approx(90.0) and r.deviation == pytest.approx(0.0, abs=1e-6) and r.pose == "lying"
    r = axis_table_angle([1.0, 1.0, 0], up)                                     # the worst case
    assert r.angle == pytest.approx(45.0) and r.deviation == pytest.approx(45.0)
    t = np.radians(30)
    for s in (1, -1):
        r = axis_table_angle([np.sin(t), s * np.cos(t), 0], up)                 # 30° from up, either sign
        assert r.angle == pytest.approx(30.0) and r.deviation == pytest.approx(30.0) and r.pose == "upright"
        r = axis_table_angle([np.cos(t), s * np.sin(t), 0], up)                 # 60° from up → 30° from lying
        assert r.angle == pytest.approx(60.0) and r.deviation == pytest.approx(30.0) and r.pose == "lying"
    r = axis_table_angle([0.0, 0.0, 1.0], [0.0, -0.8, -0.6])                    # tilted normal
    assert r.angle == pytest.approx(np.degrees(np.arccos(0.6)))
    with pytest.raises(InvalidPointsError):
        axis_table_angle([0, 0, 0], up)
    with pytest.raises(InvalidPointsError):
        axis_table_angle([np.nan, 0, 1], up)


def test_group_objects_merges_parts_and_skips_small_ones():
    label = np.zeros((40, 50), int)
    label[:, :] = 1                                                             # table
    label[0:10, 0:10] = 20                                                      # object 2, part 1 (100 px)
    label[0:5, 20:30] = 21                                                      # object 2, part 2 (50 px)
    label[20:25, 0:10] = 30                                                     # object 3: 50 px → skipped
    label[30:40, 30:50] = 45                                                    # object 4 (200 px)
    label[35:40, 0:5] = 5                                                       # table part, not an object
    label[39, 49] = 0
    valid = np.ones_like(label, bool)
    valid[30:35, 30:50] = False                                                 # half of object 4 invalid
    kept, skipped = group_objects(label, valid, min_points=64)
    assert sorted(kept) == [2, 4] and skipped == {3: 50}
    assert kept[2].sum() == 150 and kept[2][0:5, 20:30].all()
    assert kept[4].sum() == 99 and not kept[4][30:35].any()                     # 100 valid minus the label-0 pixel
    kept, skipped = group_objects(label, valid, min_points=100)
    assert sorted(kept) == [2] and skipped == {3: 50, 4: 99}
    kept, skipped = group_objects(label)
    assert kept[4].sum() == 199
    with pytest.raises(InvalidPointsError):
        group_objects(label, valid[:10])


def test_principal_axis_of_a_tilted_cylinder():
    rng = np.random.default_rng(3)
    axis = np.array([0.3, -0.9, 0.2]); axis /= np.linalg.norm(axis)
    e1 = np.cross(axis, [0.0, 0.0, 1.0]); e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    h = rng.uniform(-0.1, 0.1, 3000)                                            # 20 cm tall, 3 cm radius
    phi = rng.uniform(0, np.pi, 3000)                                           # half visible, like a depth view
    pts = np.array([0.0, 0.1, 0.9]) + h[:, None] * axis + 0.03 * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    a = principal_axis(pts)
    assert abs(np.linalg.norm(a) - 1) < 1e-9 and _angle(a, axis) < 1.0
    # a squat cylinder (bowl-like): the largest-variance direction is across, not along, the axis
    squat = np.array([0.0, 0.1, 0.9]) + (h[:, None] * 0.2) * axis + 0.06 * (np.cos(phi)[:, None] * e1
                                                                            + np.sin(phi)[:, None] * e2)
    assert _angle(principal_axis(squat), axis) > 80
    with pytest.raises(TooFewPointsError):
        principal_axis(pts[:2])


def test_summaries_and_chance_level():
    s = summarize_deviations([5.0, 15.0, 25.0, None, 1.0])
    assert s == {"n": 4, "median": 10.0, "max": 25.0, "within_10": 0.5, "within_20": 0.75}
    assert summarize_deviations([])["median"] is None
    v = np.random.default_rng(4).normal(size=(100000, 3))
    a = np.degrees(np.arccos(np.abs(v[:, 1]) / np.linalg.norm(v, axis=1)))
    d = np.minimum(a, 90 - a)
    for t in (5.0, 10.0, 20.0, 30.0):
        assert random_axis_fraction_within(t) == pytest.approx((d <= t).mean(), abs=0.01)
    assert random_axis_fraction_within(45.0) == 1.0 and random_axis_fraction_within(0.0) == 0.0
    assert random_axis_summary()["median"] == pytest.approx(np.median(d), abs=0.3)


def test_missing_scene_is_a_source_error(tmp_path):
    with pytest.raises(SourceError):
        load_labelled_scene(tmp_path / "nope.pcd")
    assert issubclass(SourceError, ValueError)


# ---------------------------------------------------------------------------------------------------- real data
def _mosd(data_root, name="learn33"):
    pytest.importorskip("pypcd4")
    path = data_root / "kinect_pcl_objects" / "mOSD_learn_cylindric" / f"{name}.pcd"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return path


def test_learn33_table_faces_the_camera_and_objects_are_found(data_root):
    scene = load_labelled_scene(_mosd(data_root))
    assert isinstance(scene, LabelledScene) and scene.xyz.shape == (480, 640, 3) and scene.rgb.shape == (480, 640, 3)
    assert np.all(np.isnan(scene.xyz[scene.label == 0][:, 2]))                  # label 0 = invalid
    assert np.all(scene.valid[scene.label > 0])
    assert abs(scene.K[0, 0] - 525) < 5 and abs(scene.K[0, 2] - 319.5) < 5
    plane = table_plane(scene)
    assert plane.normal @ -plane.centroid > 0.3                                 # towards the camera, not grazing
    assert plane.normal[1] < -0.7                                               # "up" is −y for a camera looking down
    assert plane.rms < 0.005 and plane.inliers.mean() > 0.95
    kept, skipped = group_objects(scene.label, scene.valid)
    assert len(kept) >= 1 and all(m.sum() >= 64 for m in kept.values())
    for m in kept.values():                                                     # objects stand above the table
        h = scene.xyz[m].astype(float) @ plane.normal - plane.offset
        assert np.median(h) > 0.01


def test_read_organized_pcd_contract_unchanged(data_root):
    from equipose.sources.pcd import read_organized_cloud, read_organized_pcd
    path = _mosd(data_root, "learn44")
    depth, K, rgb = read_organized_pcd(path)
    cloud = read_organized_cloud(path)
    assert depth.dtype == np.uint16 and rgb.dtype == np.uint8 and K.shape == (3, 3)
    assert np.array_equal(depth, cloud["depth"]) and np.array_equal(rgb, cloud["rgb"])
    assert set(cloud["fields"]) == {"label"} and cloud["fields"]["label"].shape == (480, 640)


def _tool():
    from equipose.eval import real_axes
    return real_axes


def test_tool_runs_one_scene_with_the_demo_model(data_root, tmp_path, capsys):
    pytest.importorskip("onnxruntime")
    data = _mosd(data_root).parent
    tool = _tool()
    out = tmp_path / "axes.json"
    rc = tool.main(["--models", "cup-tabletop", "--data", str(data), "--limit-scenes", "1", "--json", str(out),
                    "--overlays", str(tmp_path / "ov")])
    assert rc == 0
    doc = json.loads(out.read_text())
    (scene,) = doc["scenes"]
    assert scene["scene"] == "learn33" and len(doc["rows"]) == scene["num_objects"] >= 1
    for r in doc["rows"]:
        assert 0 <= r["angle"] <= 90 and r["deviation"] == pytest.approx(min(r["angle"], 90 - r["angle"]))
        assert r["axis_source"] == "symmetry_axis" and 0 <= r["baseline_deviation"] <= 45
    assert doc["summary"]["cup-tabletop"]["n"] == len(doc["rows"])
    png = tmp_path / "ov" / "learn33_cup-tabletop.png"
    assert png.is_file() and png.stat().st_size < 200_000
    assert "symmetry_axis" in capsys.readouterr().out
    assert tool.main(["--models", "no-such-model", "--data", str(data), "--json", str(out)]) == 2
    assert "no-such-model" in capsys.readouterr().err
