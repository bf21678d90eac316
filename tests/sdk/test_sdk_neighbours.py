"""The compiled nearest-neighbour search (``equipose.core.nearest``, behind ``equipose.core.neighbours``) agrees with
scipy's k-d tree by brute force and by its own tree; the compiled ICP core (``equipose.core.icp``) recovers a known
pose, keeps starts independent, holds an axis when asked and matches a plain numpy ICP step for step."""
import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from equipose import errors
from equipose.core.icp import icp_multi, kabsch
from equipose.core.neighbours import NearestNeighbours
from equipose.core.parallel import kernel_workers


@pytest.mark.parametrize("brute_max", [0, 10_000])                              # the tree, brute force
@pytest.mark.parametrize("M", [1, 3, 256, 919])
def test_compiled_search_agrees_with_a_kdtree(rng, brute_max, M):
    P = rng.normal(size=(M, 3)) * [1.0, 0.5, 0.2] + 3.0                         # off-centre: float32 must cope
    q = rng.normal(size=(2000, 3)) * 1.2 + 3.0
    d_ref, i_ref = cKDTree(P).query(q)
    d, i = NearestNeighbours(P, brute_max=brute_max).query(q)
    assert np.mean(i == i_ref) > 0.999
    np.testing.assert_allclose(d, d_ref, rtol=1e-6, atol=1e-7)                  # float32 near-ties at most
    assert d.shape == i.shape == (len(q),)
    d3, i3 = NearestNeighbours(P, brute_max=brute_max).query(q[:12].reshape(3, 4, 3))   # leading shape kept
    assert d3.shape == i3.shape == (3, 4)


@pytest.mark.parametrize("brute_max", [0, 10_000])
def test_nearest_distances_are_the_query_distances(rng, brute_max):
    from equipose.core.nearest import nearest_distances
    P = rng.normal(size=(700, 3))
    q = rng.normal(size=(300, 3))
    d = nearest_distances(P, q, brute_max)
    np.testing.assert_allclose(d, NearestNeighbours(P, brute_max=brute_max).query(q)[0], rtol=1e-15, atol=1e-15)
    assert np.all(nearest_distances(P, P[:50], brute_max) == 0.0)                # every point is its own nearest


def test_backend_errors():
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
    for workers in (2, 3, 8):                                                   # starts in parts side by side
        Rw, tw, rw = icp_multi(x, Y, starts, t0, iters=60, bidirectional=bidirectional, workers=workers)
        assert np.array_equal(Rw, R) and np.array_equal(tw, t) and np.array_equal(rw, res)
    with kernel_workers(4):                                                     # or as many as the scope allows
        Rw, _, rw = icp_multi(x, Y, starts, t0, iters=60, bidirectional=bidirectional)
    assert np.array_equal(Rw, R) and np.array_equal(rw, res)


def _numpy_icp(x, Y, R, t, iters, bidirectional):
    """A plain ICP (cKDTree pairs, SVD Kabsch, no early stop) for one start: the compiled core's reference."""
    tx, ty = cKDTree(x), cKDTree(Y)
    for it in range(iters + 1):
        local = (x - t) @ R                                                     # Rᵀ(x − t)
        d1, i1 = ty.query(local)
        res = np.mean(d1 ** 2)
        src, dst = Y[i1], x
        if bidirectional:
            d2, i2 = tx.query(Y @ R.T + t)
            res += np.mean(d2 ** 2)
            src, dst = np.concatenate([src, Y]), np.concatenate([dst, x[i2]])
        if it == iters:
            return R, t, res
        Rn, tn = kabsch(src[None], dst[None])
        R, t = Rn[0], tn[0]


@pytest.mark.parametrize("bidirectional", [False, True])
@pytest.mark.parametrize("M", [200, 700])                                       # brute force, k-d tree
def test_compiled_icp_matches_a_plain_numpy_icp(rng, bidirectional, M):
    Y = rng.normal(size=(M, 3)) * [0.6, 0.3, 0.15]
    R_true = Rotation.from_euler("xyz", [30, -20, 45], degrees=True).as_matrix()
    x = (Y[:150] @ R_true.T + [0.05, 0.0, 0.02]) + rng.normal(scale=0.01, size=(150, 3))
    R0 = Rotation.from_rotvec([0.3, -0.2, 0.25]).as_matrix() @ R_true
    R, t, res = icp_multi(x, Y, R0[None], np.zeros((1, 3)), iters=12, bidirectional=bidirectional)
    Rr, tr, rr = _numpy_icp(x, Y, R0, np.zeros(3), 12, bidirectional)
    np.testing.assert_allclose(R[0], Rr, atol=1e-9)
    np.testing.assert_allclose(t[0], tr, atol=1e-9)
    np.testing.assert_allclose(res[0], rr, rtol=1e-9)


def test_icp_holds_an_axis_on_a_direction(rng):
    Y = rng.normal(size=(300, 3)) * [0.6, 0.3, 0.15]
    up = np.array([0.0, -0.6, -0.8])
    R_true = Rotation.align_vectors([up], [[0.0, 0.0, 1.0]])[0].as_matrix()    # +z on up
    x = Y @ R_true.T
    starts = Rotation.from_rotvec(rng.normal(scale=0.2, size=(4, 3))).as_matrix() @ R_true
    R, t, res = icp_multi(x, Y, starts, np.zeros((4, 3)), iters=30, hold=(2, up * 3.0))
    np.testing.assert_allclose(R[:, :, 2], np.broadcast_to(up, (4, 3)), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0) and res.min() < 1e-8
    with pytest.raises(errors.InvalidPointsError):
        icp_multi(x, Y, starts, np.zeros((4, 3)), which=[0, 0, 1, 0])            # only one template


@pytest.mark.parametrize("n", [3, 4])
def test_top_eigenvector_matches_lapack(rng, n):
    from equipose.core.eigen import top_eigenvector
    for _ in range(50):
        A = rng.normal(size=(n, n))
        A = A + A.T
        w, V = np.linalg.eigh(A)
        v = top_eigenvector(A)
        assert abs(abs(v @ V[:, -1]) - 1.0) < 1e-10 and abs(np.linalg.norm(v) - 1.0) < 1e-12
