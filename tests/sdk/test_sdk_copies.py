"""Rotated input copies (equipose.runtime.copies) and PoseEstimator(copies=K)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose.errors import ConfigError, InvalidPointsError
from equipose.core.geometry import random_rotations, rotation_angle_deg
from equipose.runtime.copies import consensus_pose, copy_rotations, copy_samples, rotate_copies, undo_copies


def test_copy_rotations_are_fixed_and_start_with_the_identity():
    Q = copy_rotations(6)
    assert Q.shape == (6, 3, 3)
    np.testing.assert_array_equal(Q[0], np.eye(3))
    np.testing.assert_allclose(np.einsum("kij,kil->kjl", Q, Q), np.tile(np.eye(3), (6, 1, 1)), atol=1e-12)
    assert np.allclose(np.linalg.det(Q), 1.0)
    np.testing.assert_array_equal(Q, copy_rotations(6))                        # the same every time
    np.testing.assert_array_equal(Q[:3], copy_rotations(3))                   # nested: more copies add rotations
    assert copy_rotations(1).shape == (1, 3, 3)
    for bad in (0, -2, 2.5, True, 65):
        with pytest.raises(ConfigError):
            copy_rotations(bad)


def test_undo_copies_inverts_the_turn_of_each_copy():
    rng = np.random.default_rng(0)
    Q = copy_rotations(4)
    x = rng.normal(size=(2, 50, 3))
    xc = rotate_copies(x, Q)                                                   # [8, 50, 3], object b copy k at b·4+k
    assert xc.shape == (8, 50, 3) and xc.dtype == np.float32
    np.testing.assert_allclose(xc[1 * 4 + 2], x[1] @ Q[2].T, atol=1e-6)
    R = random_rotations(5, seed=3)                                            # [A=5] poses of one object …
    t = rng.normal(size=(5, 3))
    Rk = np.einsum("kij,ajl->kail", Q, R)                                      # … as an equivariant network sees them
    tk = np.einsum("kij,aj->kai", Q, t)
    R_back, t_back = undo_copies(Rk, tk, Q)
    np.testing.assert_allclose(R_back, np.broadcast_to(R, (4, 5, 3, 3)), atol=1e-12)
    np.testing.assert_allclose(t_back, np.broadcast_to(t, (4, 5, 3)), atol=1e-12)
    with pytest.raises(InvalidPointsError):
        undo_copies(Rk[:, :, :2], tk, Q)
    with pytest.raises(InvalidPointsError):
        rotate_copies(x[0], Q)


def test_copy_samples_differ_per_copy_and_ignore_the_point_order():
    from equipose.preprocess.sampling import prepare_points
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(900, 3)) * [0.05, 0.03, 0.02] + [0.0, 0.0, 0.8]    # metres
    Q = copy_rotations(5)
    prep = prepare_points(pts, 128, 0.1)
    X = copy_samples(prep.cloud, prep.model_points, Q)                         # [5, 128, 3]
    assert X.shape == (5, 128, 3) and X.dtype == np.float32
    np.testing.assert_array_equal(X[0], prep.model_points)                    # copy 0: the usual input
    keys = [set(map(tuple, np.round(x, 6))) for x in X]
    cloud = set(map(tuple, np.round(prep.cloud, 6)))
    assert all(len(k) == 128 and k <= cloud for k in keys)                     # distinct points of the object
    assert all(keys[i] != keys[j] for i in range(5) for j in range(i))         # each copy its own sample
    shuffled = prepare_points(pts[rng.permutation(len(pts))], 128, 0.1)
    Xs = copy_samples(shuffled.cloud, shuffled.model_points, Q)
    assert [set(map(tuple, np.round(x, 6))) for x in Xs] == keys               # the same samples, any point order
    few = prepare_points(pts[:100], 128, 0.1)                                  # P ≤ N: every copy holds all points
    Xf = copy_samples(few.cloud, few.model_points, Q)
    assert all(set(map(tuple, np.round(x, 6))) == set(map(tuple, np.round(few.cloud, 6))) for x in Xf)
    xc = rotate_copies(X[None], Q)                                             # [1·5, 128, 3], copy k turned by Q_k
    np.testing.assert_allclose(xc[3], X[3] @ Q[3].T, atol=1e-6)
    with pytest.raises(InvalidPointsError):
        copy_samples(prep.cloud[:, :2], prep.model_points, Q)
    with pytest.raises(InvalidPointsError):
        rotate_copies(X[None, :3], Q)                                          # K of the points ≠ K rotations


def test_consensus_averages_the_agreeing_copies_and_ignores_the_others():
    rng = np.random.default_rng(1)
    R0 = random_rotations(1, seed=7)[0]
    noise = Rotation.from_rotvec(rng.normal(scale=np.radians(2.0), size=(6, 3))).as_matrix()
    R = np.concatenate([R0 @ noise,                                           # 6 copies within a few degrees …
                        (R0 @ np.diag([1.0, -1.0, -1.0]))[None],              # … a flipped one and a far one
                        random_rotations(1, seed=11)])
    t = np.concatenate([np.full((6, 3), 0.1), np.full((2, 3), 5.0)])
    Rc, tc, support = consensus_pose(R, t)
    assert support.tolist() == [True] * 6 + [False] * 2
    assert rotation_angle_deg(Rc, R0) < 2.0
    assert np.allclose(Rc @ Rc.T, np.eye(3), atol=1e-9) and np.isclose(np.linalg.det(Rc), 1.0)
    np.testing.assert_allclose(tc, 0.1)
    # symmetric about z: copies differing only by the free turn agree; the medoid's own rotation is returned
    spin = Rotation.from_euler("z", [[0], [40], [100], [170]], degrees=True).as_matrix()
    Rs = np.einsum("ij,kjl->kil", R0, spin)
    Rc, _, support = consensus_pose(Rs, np.zeros((4, 3)), symmetry="continuous:z")
    assert support.all() and any(np.allclose(Rc, r) for r in Rs)
    with pytest.raises(InvalidPointsError):
        consensus_pose(R[:, :2], t)


def _pca_runner(num_canonical):
    """A stand-in network that is exactly rotation-equivariant: hypothesis 0 is the principal axes of the input
    (signs from the third moments), the others fixed turns of it scored worse; the canonical shape is the input in
    that frame, sorted (invariant to the point order, as a decoder's output is)."""
    turns = random_rotations(59, seed=2)

    def run(x):
        x = np.asarray(x, np.float64)
        B = len(x)
        R = np.empty((B, 60, 3, 3)); S = np.tile(np.arange(60, dtype=np.float64) + 1.0, (B, 1))
        canon = np.empty((B, num_canonical, 3))
        for b in range(B):
            w, V = np.linalg.eigh(x[b].T @ x[b])
            V = V * np.sign(((x[b] @ V) ** 3).sum(0))
            V[:, 2] *= np.linalg.det(V)
            R[b, 0], R[b, 1:] = V, V @ turns
            y = x[b] @ V
            canon[b] = np.resize(y[np.argsort(y[:, 0])], (num_canonical, 3))   # independent of the point order
        return {"hypothesis_rotations": R.astype(np.float32), "hypothesis_translations": np.zeros((B, 60, 3), np.float32),
                "hypothesis_scores": S.astype(np.float32), "canonical_shape": canon.astype(np.float32)}
    return run


def test_estimator_copies_agree_for_an_equivariant_network(tiny_model):
    from equipose import PoseEstimator
    rng = np.random.default_rng(4)
    one = PoseEstimator(tiny_model, threads=1, refine=3, copies=1)
    four = PoseEstimator(tiny_model, threads=1, refine=3, copies=4)
    # as many points as the model takes: every copy's sample holds them all, so only the turns differ
    pts = rng.gamma(2.0, size=(one.num_points, 3)) * [0.03, 0.02, 0.012]     # skewed, anisotropic: a unique frame
    pts = pts @ random_rotations(1, seed=5)[0].T + [0.02, -0.01, 0.7]
    for est in (one, four):
        est.runner = _pca_runner(est.num_canonical_points)
    r1, r4 = one.predict_points(pts), four.predict_points(pts)
    assert r1.agreement is None and "agreement" not in r1.to_dict()
    assert r4.agreement == 1.0 and r4.to_dict()["agreement"] == 1.0
    assert rotation_angle_deg(r1.rotation, r4.rotation) < 0.05
    assert np.linalg.norm(r1.translation - r4.translation) < 1e-4
    batch = four.predict_points_batch([pts, pts[::-1].copy()])                 # rows b·K + k stay with object b
    assert all(rotation_angle_deg(r.rotation, r4.rotation) < 0.05 for r in batch)


def test_estimator_copies_option(tiny_model):
    from equipose import PoseEstimator
    with pytest.raises(ConfigError):
        PoseEstimator(tiny_model, threads=1, copies=0)
    est = PoseEstimator(tiny_model, threads=1)
    assert est.copies == 1                                                    # no refine calibration: off
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(500, 3)) * [0.04, 0.03, 0.05] + [0.0, 0.0, 0.8]
    est3 = PoseEstimator(tiny_model, threads=1, refine=2, copies=3)
    r = est3.predict_points(pts)
    assert 0.0 < r.agreement <= 1.0 and np.allclose(r.rotation @ r.rotation.T, np.eye(3), atol=1e-6)
    up = np.array([0.0, -1.0, 0.0])
    r_up = est3.predict_points(pts, up=up)                                    # the up prior over the copies' starts
    assert r_up.agreement is not None and np.degrees(np.arccos(np.clip(r_up.rotation[:, 2] @ up, -1, 1))) < 1e-3


def test_large_batches_run_in_chunks(tiny_model):
    """Objects × copies beyond RUN_CHUNK go to the network in chunks (bounded memory), results in object order."""
    from equipose import PoseEstimator
    from equipose.runtime.session import RUN_CHUNK
    est = PoseEstimator(tiny_model, threads=1, refine=1, copies=3)
    net = _pca_runner(est.num_canonical_points)
    sizes = []

    def counting(x):
        sizes.append(len(x))
        return net(x)
    est.runner = counting
    rng = np.random.default_rng(6)
    base = rng.gamma(2.0, size=(est.num_points, 3)) * [0.03, 0.02, 0.012]
    turns = random_rotations(15, seed=8)
    res = est.predict_points_batch([base @ Q.T + [0.0, 0.0, 0.7] for Q in turns])   # 15 objects × 3 copies = 45
    assert max(sizes) <= RUN_CHUNK and sum(sizes) == 45
    R0 = turns[0].T @ res[0].rotation                                          # the shape's pose, turns undone
    for Q, r in zip(turns, res):                                             # each object keeps its own pose
        assert rotation_angle_deg(Q.T @ r.rotation, R0) < 0.1
