"""ICP re-scoring of the best hypotheses (equipose.runtime.refine) and PoseEstimator(refine=K)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose.errors import ConfigError, InvalidPointsError
from equipose.core.geometry import random_rotations, rotation_angle_deg
from equipose.runtime.refine import refine_hypotheses


def _tripod(rng, n):
    arm = rng.integers(0, 3, n)
    p = np.zeros((n, 3))
    p[np.arange(n), arm] = rng.uniform(0, 1, n) * np.array([0.5, 0.3, 0.15])[arm]
    return p


def test_refine_reranks_a_near_miss_above_a_better_scored_wrong_hypothesis():
    rng = np.random.default_rng(0)
    tmpl = _tripod(rng, 400)
    R_true = random_rotations(1, seed=5)[0]
    t_true = np.array([0.05, -0.02, 0.1])
    obs = tmpl[rng.permutation(400)[:256]] @ R_true.T + t_true
    A = 8
    R = random_rotations(A, seed=9)
    t = np.tile(t_true, (A, 1))
    R[3] = random_rotations(1, seed=1)[0] @ R_true                      # a far wrong pose …
    R[5] = Rotation.from_rotvec([0.15, 0.0, 0.0]).as_matrix() @ R_true  # … and an 8.6° near miss
    scores = np.linspace(1.0, 2.0, A)
    scores[3], scores[5] = 0.1, 0.2                                     # the wrong one scores best before refining
    R2, t2, s2 = refine_hypotheses(obs, tmpl, R, t, scores, k=2, iters=20)
    best = int(np.argmin(s2))
    assert best == 5 and rotation_angle_deg(R2[best], R_true) < 0.5
    assert np.linalg.norm(t2[best] - t_true) < 5e-3
    others = np.setdiff1d(np.arange(A), [3, 5])
    assert np.all(s2[others] > s2[[3, 5]].max())                        # unrefined ones rank behind, order kept
    assert np.all(np.diff(s2[others]) > 0)
    np.testing.assert_array_equal(R2[others], R[others])
    with pytest.raises(InvalidPointsError):
        refine_hypotheses(obs, tmpl, R[:, :2], t, scores)


def test_estimator_refine_option():
    from equipose import PoseEstimator
    from equipose.models import demo_model_path
    with pytest.raises(ConfigError):
        PoseEstimator(demo_model_path(), threads=1, refine=-1)
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(800, 3)) * [0.04, 0.03, 0.05] + [0.0, 0.0, 0.8]
    plain = PoseEstimator(demo_model_path(), threads=1).predict_points(pts)
    ref = PoseEstimator(demo_model_path(), threads=1, refine=3).predict_points(pts)
    assert ref.rotation.shape == (3, 3) and np.allclose(ref.rotation @ ref.rotation.T, np.eye(3), atol=1e-6)
    assert np.isfinite(ref.translation).all() and np.linalg.norm(ref.translation - plain.translation) < 0.2


def _reference_icp(x, Y, R, t, iters, bidirectional):
    """One start, every iteration, no early exit: nearest pairs → Kabsch, residual at the final pose."""
    from scipy.spatial import cKDTree
    from equipose.runtime.refine import kabsch
    ty, tx = cKDTree(Y), cKDTree(x)
    for it in range(iters + 1):
        d1, i1 = ty.query((x - t) @ R)
        res, src, dst = (d1 ** 2).mean(), Y[i1], x
        if bidirectional:
            d2, i2 = tx.query(Y @ R.T + t)
            res, src, dst = res + (d2 ** 2).mean(), np.concatenate([src, Y]), np.concatenate([dst, x[i2]])
        if it == iters:
            return R, t, res
        Rk, tk = kabsch(src[None], dst[None])
        R, t = Rk[0], tk[0]


@pytest.mark.parametrize("bidirectional", [False, True])
def test_icp_multi_early_exit_matches_every_iteration(bidirectional):
    """Starts that reach a fixed point leave early; the result equals running all iterations one start at a time."""
    from equipose.runtime.refine import icp_multi
    rng = np.random.default_rng(3)
    Y = _tripod(rng, 300)
    R_true = random_rotations(1, seed=2)[0]
    x = Y[rng.permutation(300)[:200]] @ R_true.T + [0.0, 0.0, 1.0] + rng.normal(0, 0.003, (200, 3))
    R0 = np.stack([Rotation.from_rotvec(rng.normal(0, s, 3)).as_matrix() @ R_true for s in (0.05, 0.3, 0.8, 2.0)])
    t0 = np.tile([0.0, 0.0, 1.0], (4, 1)) + rng.normal(0, 0.02, (4, 3))
    R, t, res = icp_multi(x, Y, R0, t0, iters=40, bidirectional=bidirectional)
    for j in range(4):
        Rr, tr, rr = _reference_icp(x, Y, R0[j], t0[j], 40, bidirectional)
        np.testing.assert_allclose(R[j], Rr, atol=1e-9)
        np.testing.assert_allclose(t[j], tr, atol=1e-9)
        assert res[j] == pytest.approx(rr, rel=1e-9)
    assert rotation_angle_deg(R[0], R_true) < 1.0                       # the near start converges to the truth


@pytest.mark.parametrize("bidirectional", [False, True])
def test_icp_multi_tol_stops_after_the_first_small_update(bidirectional):
    """With tol, a start stops after the first update that turns it by < tol rad and moves it by < tol: the result
    is the plain ICP's after that many updates, with that pose's residual."""
    from equipose.runtime.refine import icp_multi
    rng = np.random.default_rng(5)
    Y = _tripod(rng, 300)
    R_true = random_rotations(1, seed=4)[0]
    x = Y[rng.permutation(300)[:200]] @ R_true.T + [0.0, 0.0, 1.0] + rng.normal(0, 0.003, (200, 3))
    R0 = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix() @ R_true
    t0 = np.array([0.0, 0.0, 1.0]) + rng.normal(0, 0.02, 3)
    tol = 2e-3
    poses = [(R0, t0)]
    for k in range(1, 40):
        poses.append(_reference_icp(x, Y, R0, t0, k, bidirectional)[:2])
    steps = [(rotation_angle_deg(poses[k][0], poses[k - 1][0]), np.linalg.norm(poses[k][1] - poses[k - 1][1]))
             for k in range(1, 40)]
    first = next(k + 1 for k, (a, d) in enumerate(steps) if np.radians(a) < tol and d < tol)
    assert 1 < first < 39                                                    # the test exercises an early stop
    R, t, res = icp_multi(x, Y, R0[None], t0[None], iters=40, bidirectional=bidirectional, tol=tol)
    Rr, tr, rr = _reference_icp(x, Y, R0, t0, first, bidirectional)
    np.testing.assert_allclose(R[0], Rr, atol=1e-9)
    np.testing.assert_allclose(t[0], tr, atol=1e-9)
    assert res[0] == pytest.approx(rr, rel=1e-9)


def _box_surface(rng, n, size=(0.4, 0.25, 0.15)):
    """[n, 3] points on the faces of a box centred at the origin, and their face normals [n, 3]."""
    face = rng.integers(0, 6, n)
    axis, sign = face % 3, np.where(face < 3, 1.0, -1.0)
    half = np.array(size) / 2
    p = rng.uniform(-1, 1, (n, 3)) * half
    p[np.arange(n), axis] = sign * half[axis]
    normals = np.zeros((n, 3))
    normals[np.arange(n), axis] = sign
    return p, normals


def test_point_normals_of_a_box_are_its_face_normals():
    from equipose.core.normals import point_normals
    rng = np.random.default_rng(2)
    half = np.array([0.4, 0.25, 0.15]) / 2
    p, normals = _box_surface(rng, 3000)
    on_face = np.abs(normals) > 0.5                                             # [n, 3] the face's own axis
    inner = np.all(on_face | (np.abs(p) < half - 0.03), axis=1)                 # 3 cm or more from every edge
    cos = np.abs(np.sum(point_normals(p)[inner] * normals[inner], axis=1))
    assert inner.sum() > 1000 and np.median(cos) > 0.999 and np.mean(cos > 0.99) > 0.95


def test_point_to_plane_icp_recovers_a_pose_that_point_to_point_leaves_creeping():
    from equipose.core.icp import icp_multi, icp_point_to_plane
    rng = np.random.default_rng(4)
    tmpl, normals = _box_surface(rng, 1024)
    R_true = random_rotations(1, seed=3)[0]
    t_true = np.array([0.02, -0.03, 0.6])
    obs_obj, _ = _box_surface(np.random.default_rng(5), 400)                  # other samples of the same surface
    obs = obs_obj @ R_true.T + t_true + rng.normal(scale=0.001, size=obs_obj.shape)
    R0 = (Rotation.from_rotvec([0.12, -0.08, 0.1]).as_matrix() @ R_true)[None]   # about 10° off
    t0 = (t_true + np.array([0.01, 0.01, -0.01]))[None]
    R, t, res = icp_point_to_plane(obs, tmpl, normals, R0, t0, iters=15)
    assert rotation_angle_deg(R[0], R_true) < 0.5 and np.linalg.norm(t[0] - t_true) < 0.002
    _, _, res0 = icp_multi(obs, tmpl, R, t, iters=0)                            # its residual is icp_multi's
    np.testing.assert_allclose(res, res0, rtol=1e-9)
    Rp, _, _ = icp_multi(obs, tmpl, R0, t0, iters=15)                           # the same 15 steps point-to-point
    assert rotation_angle_deg(R[0], R_true) < rotation_angle_deg(Rp[0], R_true)


def test_trimmed_point_to_plane_icp_is_not_pulled_by_a_neighbour_in_the_crop():
    from equipose.core.icp import icp_point_to_plane
    rng = np.random.default_rng(9)
    tmpl, normals = _box_surface(rng, 1024)
    R_true = random_rotations(1, seed=10)[0]
    t_true = np.array([0.0, 0.0, 0.6])
    obs = _box_surface(np.random.default_rng(11), 400)[0] @ R_true.T + t_true
    beside = rng.uniform(-0.05, 0.05, (250, 3)) + t_true + [0.12, 0.0, 0.0]    # a neighbour's points, 12 cm away
    x = np.vstack([obs, beside])
    R0 = (Rotation.from_rotvec([0.05, -0.04, 0.03]).as_matrix() @ R_true)[None]
    t0 = (t_true + [0.005, -0.005, 0.0])[None]
    Ru, tu, _ = icp_point_to_plane(x, tmpl, normals, R0, t0, iters=30)
    Rt, tt, rt = icp_point_to_plane(x, tmpl, normals, R0, t0, iters=30, max_dist=0.01)
    assert rotation_angle_deg(Rt[0], R_true) < 0.5 and np.linalg.norm(tt[0] - t_true) < 0.002
    assert np.linalg.norm(tu[0] - t_true) > 0.01                                # untrimmed: pulled towards it
    _, _, ru = icp_point_to_plane(x, tmpl, normals, Ru, tu, iters=0, max_dist=0.01)
    assert rt[0] < ru[0] <= 0.01 ** 2                                           # truncated: at most max_dist²
    _, _, r_same = icp_point_to_plane(obs, tmpl, normals, R0, t0, iters=30, max_dist=1.0)
    _, _, r_plain = icp_point_to_plane(obs, tmpl, normals, R0, t0, iters=30)
    np.testing.assert_allclose(r_same, r_plain, rtol=1e-9)                     # nothing beyond it: the plain ICP
    with pytest.raises(InvalidPointsError):
        icp_point_to_plane(x, tmpl, normals, R0, t0, max_dist=-1.0)


def test_point_to_plane_icp_refuses_mismatched_normals():
    from equipose.core.icp import icp_point_to_plane
    with pytest.raises(InvalidPointsError):
        icp_point_to_plane(np.zeros((10, 3)), np.ones((20, 3)), np.ones((19, 3)), np.eye(3)[None], np.zeros((1, 3)))


def test_refine_hypotheses_point_to_plane_matches_the_core_and_is_one_way():
    from equipose.core.icp import icp_point_to_plane
    rng = np.random.default_rng(6)
    tmpl, normals = _box_surface(rng, 512)
    R_true = random_rotations(1, seed=7)[0]
    obs = _box_surface(np.random.default_rng(8), 300)[0] @ R_true.T
    R = np.stack([Rotation.from_rotvec(rng.normal(size=3) * 0.1).as_matrix() @ R_true for _ in range(6)])
    t, scores = np.zeros((6, 3)), np.arange(6.0)[::-1]
    R2, t2, s2 = refine_hypotheses(obs, tmpl, R, t, scores, k=3, iters=10, normals=normals, tol=1e-6)
    top = np.argsort(scores)[:3]
    Rc, tc, rc = icp_point_to_plane(obs, tmpl, normals, R[top], t[top], iters=10, tol=1e-6)
    np.testing.assert_array_equal(R2[top], Rc)
    np.testing.assert_array_equal(s2[top], rc)
    with pytest.raises(ConfigError):
        refine_hypotheses(obs, tmpl, R, t, scores, k=3, normals=normals, bidirectional=True)
