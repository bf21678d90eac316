"""View-aware re-scoring (equipose.runtime.visibility) and PoseEstimator(visibility=...)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose.errors import ConfigError, InvalidPointsError
from equipose.preprocess.sampling import PreparedPoints
from equipose.runtime.visibility import view_rescore, view_residuals, visible_mask


def _plates(n: int = 12) -> np.ndarray:
    """Two parallel unit squares 1 apart (z = ∓0.5), [2·n², 3]: a box's front and back faces."""
    g = np.linspace(-0.5, 0.5, n)
    sq = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    return np.concatenate([np.c_[sq, np.full(len(sq), -0.5)], np.c_[sq, np.full(len(sq), 0.5)]])


def test_visible_mask_keeps_the_side_facing_the_camera():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centre = np.array([0.3, -0.2, 5.0])
    m = visible_mask(centre + d, np.zeros(3))
    facing = d @ (-centre / np.linalg.norm(centre))                         # cos to the direction of the camera
    assert 0.2 < m.mean() < 0.6
    assert facing[m].min() > -0.05                                           # nothing from the far side
    assert m[facing > 0.5].mean() > 0.9                                      # the near cap is seen
    for bad in (np.zeros((3, 3)), np.zeros((10, 2))):
        with pytest.raises(InvalidPointsError):
            visible_mask(bad, np.zeros(3))
    with pytest.raises(InvalidPointsError):
        visible_mask(np.full((10, 3), np.nan), np.zeros(3))
    np.testing.assert_array_equal(visible_mask(np.c_[rng.normal(size=(50, 2)), np.ones(50)], np.zeros(3)), True)


def _box_scene():
    """The plates' front face seen from the origin at z = 4, and two poses that both put a face exactly there."""
    T = _plates()
    R1, t1 = np.eye(3), np.array([0.0, 0.0, 4.5])                             # front face at z = 4, back at 5
    R2 = Rotation.from_euler("y", 180, degrees=True).as_matrix()             # turned about the front face's centre:
    t2 = np.array([0.0, 0.0, 3.5])                                           # back face at z = 3, in front of it
    obs = T[T[:, 2] < 0] @ R1.T + t1                                         # what the camera saw: one square at z = 4
    return T, obs, np.stack([R1, R2]), np.stack([t1, t2])


def test_view_residual_charges_visible_template_parts_the_view_lacks():
    T, obs, R, t = _box_scene()
    one_way = [np.mean(np.min(np.linalg.norm(obs[:, None] - (T @ r.T + tt)[None], axis=2), 1) ** 2)
               for r, tt in zip(R, t)]
    assert max(one_way) < 1e-12                                              # ICP's residual cannot tell them apart
    v = view_residuals(obs, T, R, t, np.zeros(3))
    assert v[0] < 1e-3 and v[1] > 0.5                                        # the second shows a face not observed
    with pytest.raises(InvalidPointsError):
        view_residuals(obs, T, R, t[:1], np.zeros(3))


def test_view_rescore_ranks_distinct_poses_and_keeps_groups_together():
    T, obs, R, t = _box_scene()
    centre = obs.mean(0)
    prep = PreparedPoints(model_points=obs - centre, centre_m=centre, scale=1.0, order=np.arange(len(obs)))   # centred
    near = Rotation.from_euler("z", 4, degrees=True).as_matrix() @ R[1]      # a near-duplicate of the wrong pose
    Rs = np.stack([R[1], near, R[0], np.eye(3)])
    ts = np.stack([t[1], t[1], t[0], t[0]]) - centre
    s = np.array([1.0, 2.0, 3.0, 9.0])                                       # the old ranking prefers the wrong pose
    out = view_rescore(prep, T, Rs, ts, s, k=3)
    assert np.argmin(out) == 2                                               # the right pose wins …
    assert out[0] < out[1] < out[3]                                          # … its near-duplicate stays behind the head,
    assert out[3] == out.max()                                               # the unrefined one behind them all
    kept = view_rescore(prep, T, Rs[[2, 0]], ts[[2, 0]], np.array([1.0, 2.0]), k=2)
    assert np.argmin(kept) == 0                                              # a right incumbent stays first
    close = view_rescore(prep, T, Rs[[0, 2]], ts[[0, 2]], np.array([1.0, 2.0]), k=2, margin=1.0)
    assert np.argmin(close) == 0                                             # margin 1: the incumbent always stays
    votes = np.stack([R[1]] * 7 + [R[0]])                                    # 7 of 8 copies found the wrong pose
    out = view_rescore(prep, T, Rs[[2, 0]], ts[[2, 0]], np.array([1.0, 2.0]), k=2, copy_poses=votes)
    assert np.argmin(out) == 0                                               # the view still decides at weight 0.8 …
    off = PreparedPoints(model_points=prep.model_points + [0.0, 0.0, 0.02], centre_m=centre, scale=1.0,
                         order=prep.order)
    out = view_rescore(off, T, Rs[[2, 0]], ts[[2, 0]], np.array([1.0, 2.0]), k=2, copy_poses=votes[:7],
                       support_weight=1.0)                                   # (the right pose's residual now > 0)
    assert np.argmin(out) == 1                                               # … a unanimous vote at weight 1 overrides it
    with pytest.raises(InvalidPointsError, match="copy_poses"):
        view_rescore(prep, T, Rs, ts, s, k=2, copy_poses=np.eye(3))


def test_estimator_visibility_option(tiny_model):
    from equipose import PoseEstimator
    est = PoseEstimator(tiny_model, threads=1, refine=3, visibility=1.0)
    assert est.visibility == 1.0 and PoseEstimator(tiny_model, threads=1).visibility is None   # no metadata: off
    rng = np.random.default_rng(1)
    pts = rng.normal(scale=0.05, size=(400, 3)) + [0.0, 0.0, 0.8]
    r = est.predict_points(pts)
    assert np.allclose(r.rotation @ r.rotation.T, np.eye(3), atol=1e-6) and np.isfinite(r.score)
    for bad in ("on", True, 7.0):
        with pytest.raises(ConfigError):
            PoseEstimator(tiny_model, threads=1, visibility=bad)


def test_estimator_polish_option(tiny_model):
    """polish: more ICP iterations on the selected pose; it needs the re-scoring and only moves the pose toward a
    better fit of the predicted shape."""
    from equipose import PoseEstimator
    from equipose.runtime.refine import icp_multi
    pts = np.random.default_rng(1).normal(scale=0.05, size=(400, 3)) + [0.0, 0.0, 0.8]
    base = PoseEstimator(tiny_model, threads=1, refine=3)
    est = PoseEstimator(tiny_model, threads=1, refine=3, polish=20)
    assert base.polish == 0 and est.polish == 20
    r0, r1 = base.predict_points(pts), est.predict_points(pts)
    assert np.allclose(r1.rotation @ r1.rotation.T, np.eye(3), atol=1e-6)

    def residual(r):                                                         # observed points → posed shape, m²
        return float(icp_multi(pts, r.canonical_shape_object, r.rotation[None], r.translation[None], iters=0)[2][0])
    assert residual(r1) <= residual(r0) + 1e-12
    for bad in (-1, 1.5, True, "more"):
        with pytest.raises(ConfigError, match="polish"):
            PoseEstimator(tiny_model, threads=1, refine=3, polish=bad)
    with pytest.raises(ConfigError, match="refine"):
        PoseEstimator(tiny_model, threads=1, refine=0, polish=5)
    loose = PoseEstimator(tiny_model, threads=1, refine=3, polish=20, stages={"polish": {"tol": 0.05}})
    assert loose.pipeline.get("polish").describe()["tol"] == 0.05
    r2 = loose.predict_points(pts)                                           # stops early: no better than 20 updates
    assert residual(r1) <= residual(r2) + 1e-12 and residual(r2) <= residual(r0) + 1e-12
    for bad in (-0.1, 0.5, True, "small"):
        with pytest.raises(ConfigError, match="polish tol"):
            PoseEstimator(tiny_model, threads=1, refine=3, polish=20, stages={"polish": {"tol": bad}})


def test_visibility_is_refused_for_complete_shape_models(tmp_path):
    pytest.importorskip("torch")
    from equipose import PoseEstimator
    from equipose.export.onnx_export import export_random_model
    path = tmp_path / "complete.onnx"
    export_random_model("tiny", path, partial=False, category="mug", scale=0.25, verify=False)
    with pytest.raises(ConfigError, match="partial-view"):
        PoseEstimator(path, threads=1, refine=3, visibility=1.0)
    assert PoseEstimator(path, threads=1, refine=3).visibility is None


def test_view_stage_ranks_its_k_best(tiny_model, monkeypatch):
    """stage option view k: how many of the best re-scored poses the view-aware residual ranks ("auto": all)."""
    from equipose import PoseEstimator
    import equipose.runtime.stages.view as view_stage
    seen = []

    def spy(*args, k, **kwargs):
        seen.append(k)
        return view_rescore(*args, k=k, **kwargs)
    monkeypatch.setattr(view_stage, "view_rescore", spy)
    pts = np.random.default_rng(1).normal(scale=0.05, size=(400, 3)) + [0.0, 0.0, 0.8]
    auto = PoseEstimator(tiny_model, threads=1, refine=4, visibility=1.0)
    two = PoseEstimator(tiny_model, threads=1, refine=4, visibility=1.0, stages={"view": {"k": 2}})
    assert auto.pipeline.get("view").describe()["k"] == 4 and two.pipeline.get("view").describe()["k"] == 2
    auto.predict_points(pts)
    two.predict_points(pts)
    assert seen == [4, 2]
    for bad in (0, 2.5, True, "all"):
        with pytest.raises(ConfigError, match="view k"):
            PoseEstimator(tiny_model, threads=1, refine=4, visibility=1.0, stages={"view": {"k": bad}})
