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
