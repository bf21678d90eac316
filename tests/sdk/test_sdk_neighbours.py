"""Nearest-neighbour backends (``equipose.core.neighbours``) agree with a k-d tree; the batched ICP core
(``equipose.core.icp``) recovers a known pose with every backend and keeps starts independent."""
import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from equipose import errors
from equipose.core.icp import icp_multi, kabsch
from equipose.core.neighbours import GEMM_CHUNK_ENTRIES, NearestNeighbours, choose_backend


@pytest.mark.parametrize("backend", ["gemm", "small_gicp", "kdtree"])
@pytest.mark.parametrize("M", [3, 256, 919])
def test_backends_agree_with_a_kdtree(rng, backend, M):
    P = rng.normal(size=(M, 3)) * [1.0, 0.5, 0.2] + 3.0                         # off-centre: float32 must cope
    q = rng.normal(size=(GEMM_CHUNK_ENTRIES // M + 7, 3)) * 1.2 + 3.0          # more queries than one chunk
    d_ref, i_ref = cKDTree(P).query(q)
    d, i = NearestNeighbours(P, backend).query(q)
    assert np.mean(i == i_ref) > 0.999
    np.testing.assert_allclose(d, d_ref, atol=1e-9)
    assert d.shape == i.shape == (len(q),)
    d3, i3 = NearestNeighbours(P, backend).query(q[:12].reshape(3, 4, 3))       # leading shape kept
    assert d3.shape == i3.shape == (3, 4)


def test_backend_choice_and_errors():
    assert choose_backend(256) == "gemm" and choose_backend(5000) in ("small_gicp", "kdtree")
    with pytest.raises(errors.ConfigError):
        NearestNeighbours(np.zeros((4, 3)), "faiss")
    with pytest.raises(errors.InvalidPointsError):
        NearestNeighbours(np.zeros((4, 2)))


def test_kabsch_is_a_proper_rotation_even_for_reflected_pairs(rng):
    src = rng.normal(size=(4, 50, 3))
    dst = src * [-1.0, 1.0, 1.0]                                                # a mirror image: best fit is not a
    R, t = kabsch(src, dst)                                                     # rotation, so det must stay +1
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    R_true = Rotation.random(4, random_state=1).as_matrix()
    R2, t2 = kabsch(src, np.einsum("bij,bkj->bki", R_true, src) + [0.1, 0.0, -0.2])
    np.testing.assert_allclose(R2, R_true, atol=1e-9)
    np.testing.assert_allclose(t2, np.broadcast_to([0.1, 0.0, -0.2], (4, 3)), atol=1e-9)


@pytest.mark.parametrize("bidirectional", [False, True])
def test_batched_icp_starts_are_independent_and_converge(rng, bidirectional):
    Y = rng.normal(size=(300, 3)) * [0.6, 0.3, 0.15]
    R_true = Rotation.from_euler("xyz", [20, -10, 35], degrees=True).as_matrix()
    x = Y @ R_true.T + [0.05, 0.0, 0.02]
    starts = Rotation.from_rotvec(rng.normal(scale=0.15, size=(6, 3))).as_matrix() @ R_true
    t0 = np.zeros((6, 3))
    R, t, res = icp_multi(x, Y, starts, t0, iters=60, bidirectional=bidirectional)
    for j in range(6):                                                          # each start alone: the same answer
        Rj, tj, rj = icp_multi(x, Y, starts[j:j + 1], t0[j:j + 1], iters=60, bidirectional=bidirectional)
        np.testing.assert_allclose(Rj[0], R[j], atol=1e-12)
        np.testing.assert_allclose(rj[0], res[j], atol=1e-15)
    best = int(np.argmin(res))
    assert np.degrees(np.arccos(np.clip((np.trace(R[best].T @ R_true) - 1) / 2, -1, 1))) < 0.5
