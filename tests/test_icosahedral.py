import numpy as np
import pytest

from equipose.core import icosahedral as I
def test_rotations_are_orthonormal_proper():
    A = I.ANCHORS
    assert A.shape == (60, 3, 3)
    assert np.abs(A @ A.transpose(0, 2, 1) - np.eye(3)).max() < 1e-12
    assert np.allclose(np.linalg.det(A), 1.0)


def test_identity_index():
    assert I.IDENTITY_INDEX == 29
    assert np.allclose(I.ANCHORS[29], np.eye(3), atol=1e-12)
    assert (I.CAYLEY[29] == np.arange(60)).all() and (I.CAYLEY[:, 29] == np.arange(60)).all()


def test_closure_and_cayley_latin_square():
    A = I.ANCHORS
    prod = np.einsum("iab,jbc->ijac", A, A)
    assert np.abs(prod - A[I.CAYLEY]).max() < 1e-12          # closed under products
    for row in I.CAYLEY:                                         # each row/column a permutation
        assert sorted(row) == list(range(60))
    for col in I.CAYLEY.T:
        assert sorted(col) == list(range(60))


def test_associativity():
    C = I.CAYLEY
    i, j, k = np.meshgrid(np.arange(0, 60, 7), np.arange(0, 60, 5), np.arange(60), indexing="ij")
    assert (C[C[i, j], k] == C[i, C[j, k]]).all()


def test_inverse_table():
    assert (I.CAYLEY[np.arange(60), I.INVERSE] == 29).all()
    assert (I.CAYLEY[I.INVERSE, np.arange(60)] == 29).all()
    assert I.INVERSE[0] == 15 and I.INVERSE[29] == 29


def test_angle_classes():
    ang = np.degrees(np.arccos(np.clip((np.trace(I.ANCHORS, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    counts = {a: int(np.sum(np.abs(ang - a) < 1e-3)) for a in (0, 72, 120, 144, 180)}
    assert counts == {0: 1, 72: 12, 120: 20, 144: 12, 180: 15}


def test_intra_table_is_right_multiplication():
    H = I.INTRA_GENERATORS
    assert I.INTRA_NEIGHBOURS.shape == (60, 12)
    for g in range(60):
        for k in range(12):
            assert I.INTRA_NEIGHBOURS[g, k] == I.CAYLEY[g, H[k]]
            assert np.allclose(I.ANCHORS[I.INTRA_NEIGHBOURS[g, k]], I.ANCHORS[g] @ I.ANCHORS[H[k]])
    assert (I.INTRA_NEIGHBOURS[:, 9] == np.arange(60)).all()      # column 9 is the identity
    # spec Appendix B, first row
    assert list(I.INTRA_NEIGHBOURS[0]) == [10, 33, 13, 15, 56, 30, 59, 8, 44, 0, 45, 26]


def test_left_multiplication_permutes_anchor_indices():
    # rotating by g maps anchor a to anchor CAYLEY[g, a] and commutes with the intra table
    for g in (0, 7, 13, 42):
        moved = np.einsum("ij,ajk->aik", I.ANCHORS[g], I.ANCHORS)
        assert np.allclose(moved, I.ANCHORS[I.CAYLEY[g]], atol=1e-12)
        assert (I.CAYLEY[g][I.INTRA_NEIGHBOURS] == I.INTRA_NEIGHBOURS[I.CAYLEY[g]]).all()


def test_vertices_and_permutation():
    V = I.VERTICES
    assert V.shape == (12, 3) and np.allclose(np.linalg.norm(V, axis=1), 1)
    d = V @ V.T
    off = np.sort(np.round(d[0], 6))
    assert np.isclose(off[0], -1) and np.isclose(off[-1], 1)
    assert np.sum(np.isclose(off, 1 / np.sqrt(5), atol=1e-6)) == 5   # 5 neighbours per vertex
    for g in range(60):
        assert sorted(I.VERTEX_PERMUTATION[g]) == list(range(12))
        assert np.allclose(V @ I.ANCHORS[g].T, V[I.VERTEX_PERMUTATION[g]], atol=1e-9)
    # permutations compose like the group
    for g, h in ((3, 17), (40, 59)):
        assert (I.VERTEX_PERMUTATION[I.CAYLEY[g, h]] == I.VERTEX_PERMUTATION[g][I.VERTEX_PERMUTATION[h]]).all()


def test_kernel_points():
    k = I.kernel_points(24, 0.056)
    assert k.shape == (24, 3) and np.allclose(k[0], 0)
    assert np.isclose(np.linalg.norm(k, axis=1).max(), 0.056)
    assert I.kernel_points(13, 1.0).shape == (13, 3)
    with pytest.raises(ValueError):
        I.kernel_points(7, 1.0)


def test_quaternions_match_matrices():
    from equipose.core.geometry import quaternion_to_matrix
    q = I.ANCHOR_QUATERNIONS
    assert (q[:, 0] >= 0).all() and np.allclose(np.linalg.norm(q, axis=1), 1)
    assert np.allclose(quaternion_to_matrix(q), I.ANCHORS, atol=1e-12)


def test_rotation_index():
    assert I.rotation_index(I.ANCHORS[17]) == 17
    with pytest.raises(ValueError):
        I.rotation_index(np.array([[1, 0, 0], [0, np.cos(0.1), -np.sin(0.1)], [0, np.sin(0.1), np.cos(0.1)]]))
