"""The up prior (``equipose.runtime.upright``): argument checks, the stage on synthetic hypotheses with a known answer,
the estimator's ``up=`` paths, and a rendered laptop standing on a table (``up="plane"``)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors
from equipose.core.geometry import rotation_angle_deg, rotation_between
from equipose.core.icosahedral import ANCHORS
from equipose.runtime.upright import check_up, per_object_up, select_upright


@pytest.mark.parametrize("bad", [[0, 0, 0], [1, 2], [np.nan, 0, 1], "table", object(), [[0, 0, 1]]])
def test_check_up_rejects_bad_values(bad):
    with pytest.raises(errors.ConfigError):
        check_up(bad)


def test_check_up_normalises_and_plane_needs_a_frame():
    np.testing.assert_allclose(check_up([0, -2, 0]), [0, -1, 0])
    assert check_up("plane") == "plane"
    with pytest.raises(errors.ConfigError, match="depth frame"):
        check_up("plane", allow_plane=False)


def test_per_object_up_shapes():
    assert per_object_up(None, 2) == [None, None]
    shared = per_object_up([0, 0, 1], 3)
    assert len(shared) == 3 and all(np.allclose(u, [0, 0, 1]) for u in shared)
    mixed = per_object_up([None, [1, 0, 0]], 2)
    assert mixed[0] is None and np.allclose(mixed[1], [1, 0, 0])
    with pytest.raises(errors.ConfigError, match="entries"):
        per_object_up([[0, 0, 1], [0, 1, 0]], 3)


def test_rotation_between_includes_the_half_turn():
    for a, b in (([0, 0, 1], [0, 1, 0]), ([1, 2, 3], [-1, -2, -3]), ([0, 0, 1], [0, 0, 1])):
        R = rotation_between(a, b)
        np.testing.assert_allclose(R @ (np.array(a) / np.linalg.norm(a)), np.array(b) / np.linalg.norm(b), atol=1e-12)
        assert np.isclose(np.linalg.det(R), 1.0)


def _l_shape(rng):
    """An asymmetric 'laptop': a base plate and a raised back plate of different sizes (category frame, +z up)."""
    base = np.c_[rng.uniform(-1, 1, 400), rng.uniform(-0.7, 0.7, 400), np.zeros(400)]
    back = np.c_[np.full(250, -1.0), rng.uniform(-0.7, 0.7, 250), rng.uniform(0, 1.3, 250)]
    return np.vstack([base, back]) - [0.0, 0.0, 0.3]


def test_select_upright_recovers_a_known_pose(rng):
    y = _l_shape(rng)                                                           # [M, 3] template, category frame
    R_true = Rotation.from_euler("zyx", [35, -50, 20], degrees=True).as_matrix()
    t_true = np.array([0.05, -0.02, 0.1])
    x = y[rng.choice(len(y), 300, replace=False)] @ R_true.T + t_true          # observation
    up = R_true[:, 2]
    scores = rng.uniform(0.5, 1.0, 60)                                          # the network's ranking: no help
    sel, R, t = select_upright(x, y, ANCHORS, np.zeros((60, 3)), scores, up)
    assert rotation_angle_deg(R, R_true) < 2.0
    np.testing.assert_allclose(R[:, 2], up, atol=1e-9)                          # the up axis is held exactly
    assert np.linalg.norm(t - t_true) < 0.02
    assert not sel.ambiguous and 0.0 <= sel.confidence <= 1.0 and sel.top_k[0]["index"] == sel.index


def test_select_upright_reports_front_back_ambiguity(rng):
    def box(n):                                                                 # a solid box: front and back alike
        return np.c_[rng.uniform(-1, 1, n), rng.uniform(-0.5, 0.5, n), rng.uniform(-0.3, 0.3, n)]
    R_true = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    sel, R, _ = select_upright(box(300) @ R_true.T, box(800), ANCHORS, np.zeros((60, 3)), np.ones(60), R_true[:, 2])
    assert sel.ambiguous and sel.flip >= 0


def test_estimator_up_holds_the_axis_and_is_reported(estimator, rng):
    pts = rng.normal(size=(400, 3)) * [0.04, 0.03, 0.05] + [0.0, 0.0, 0.7]
    up = np.array([0.1, -0.9, -0.3])
    res = estimator.predict_points(pts, up=up)
    u = up / np.linalg.norm(up)
    np.testing.assert_allclose(res.rotation[:, 2], u, atol=1e-9)
    np.testing.assert_allclose(res.up, u)
    assert res.to_dict()["up"] == pytest.approx(list(u), abs=1e-6)
    assert "up-prior" in res.summary()
    assert estimator.predict_points(pts).up is None
    with pytest.raises(errors.ConfigError):
        estimator.predict_points(pts, up="plane")
    batch = estimator.predict_points_batch([pts, pts], up=[None, up])
    assert batch[0].up is None and np.allclose(batch[1].rotation[:, 2], u)


def test_up_plane_on_a_tabletop_frame(estimator):
    from conftest import K_VGA, tabletop_scene
    depth, masks = tabletop_scene()
    n_true = np.array([0.0, -0.96, -0.28]) / np.linalg.norm([0.0, -0.96, -0.28])    # the scene's table normal: up
    ys, xs = np.nonzero(masks[0])
    box = (int(xs.min()), int(ys.min()), int(np.ptp(xs) + 1), int(np.ptp(ys) + 1))
    res = estimator.predict(depth, K_VGA, box=box, up="plane")
    assert np.degrees(np.arccos(np.clip(res.up @ n_true, -1, 1))) < 1.0
    np.testing.assert_allclose(res.rotation[:, 2], res.up, atol=1e-9)
    planeless = np.where(masks[0], depth, 0).astype(np.uint16)                  # no table in the frame: no prior
    assert estimator.predict(planeless, K_VGA, mask=masks[0], up="plane").up is None


def test_instance_mode_refuses_the_up_prior(tiny_model, rng):
    est = PoseEstimator(tiny_model, model_points=rng.normal(size=(500, 3)) * 0.05)
    with pytest.raises(errors.ConfigError, match="instance"):
        est.predict_points(rng.normal(size=(300, 3)) * 0.05 + [0, 0, 0.6], up=[0, -1, 0])


def test_laptop_standing_on_a_table_known_answer(data_root):
    """Shipped ``laptop-partial`` on rendered laptops standing on a table: the plane gives up, the pose is found."""
    from equipose.train.data.render_cache import modelnet_shapes
    from equipose.train.data.scene import render_standing
    est = PoseEstimator("laptop-partial")
    rng = np.random.default_rng(0)
    errs = []
    for _, shape, _ in modelnet_shapes(data_root, "laptop", "test", "npy1024", 3):
        v = render_standing(shape, rng)
        res = est.predict(v["depth"], v["K"], box=v["box"], up="plane")
        assert np.degrees(np.arccos(np.clip(res.up @ v["R"][:, 2], -1, 1))) < 1.0   # the table's normal is up
        errs.append(rotation_angle_deg(res.rotation, v["R"]))
    assert np.median(errs) < 10.0, errs


def test_select_upright_keeps_given_starts_and_flags_a_better_partner(rng):
    y = _l_shape(rng)
    R_true = Rotation.from_euler("zyx", [35, -50, 20], degrees=True).as_matrix()
    x = y[rng.choice(len(y), 300, replace=False)] @ R_true.T
    hyps = ANCHORS.copy()
    hyps[0] = R_true @ np.diag([-1.0, -1.0, 1.0])                               # an azimuth off by a half turn
    sel, R, _ = select_upright(x, y, hyps, np.zeros((60, 3)), np.ones(60), R_true[:, 2], starts=[0])
    assert sel.index == 0 and rotation_angle_deg(R, R_true) > 150               # kept, not silently turned ...
    assert sel.ambiguous and sel.flip_margin < 0                                # ... but reported: the partner fits better
    sel2, R2, _ = select_upright(x, y, hyps, np.zeros((60, 3)), np.ones(60), R_true[:, 2])
    assert rotation_angle_deg(R2, R_true) < 2.0                                 # free selection takes the partner


def test_a_bowl_seen_from_above_stands_on_the_plane():
    """A shallow bowl seen from above shows mostly its inside floor, just above the table: with 30 % of its points
    more than 12 mm up it stands on the plane; a flat face that is the "plane" itself (10 % up) does not."""
    from equipose.runtime.upright import resolve_support_plane
    rng = np.random.default_rng(0)
    n, offset = np.array([0.0, -0.6, -0.8]), 0.7                               # unit normal towards the camera
    base = rng.normal(size=(1000, 3)) * 0.05
    base -= np.outer(base @ n + offset, n)                                     # [1000, 3] on the plane
    for share, stands in ((0.30, True), (0.10, False)):
        heights = np.where(np.arange(1000) < share * 1000, 0.03, 0.005)         # m above the plane
        support = resolve_support_plane((n, offset), base + np.outer(heights, n))
        assert (support is not None) is stands
        if stands:
            assert np.allclose(support[0], n) and np.isclose(support[1], offset)
