"""Hypothesis selection, confidence, ambiguity, symmetry and calibration on hand-built cases."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose.runtime.hypotheses import (apply_calibration, canonicalise_rotation, select_hypothesis,
                                 symmetric_distance_deg)


def rot(axis, deg):
    return Rotation.from_rotvec(np.radians(deg) * np.asarray(axis, float)).as_matrix()


def hyps(scores):
    """I, 10° about z (a near duplicate), 90° about x, 180° about x."""
    R = np.stack([np.eye(3), rot([0, 0, 1], 10), rot([1, 0, 0], 90), rot([1, 0, 0], 180)])
    return R, np.zeros((4, 3)), np.asarray(scores, float)


def test_confidence_uses_the_best_hypothesis_more_than_30_degrees_away():
    sel = select_hypothesis(*hyps([0.10, 0.1001, 0.20, 0.50]))
    assert sel.index == 0
    assert sel.runner_up == 2                                                   # the 10° twin does not count
    assert sel.confidence == pytest.approx((0.20 - 0.10) / 0.20)
    assert not sel.ambiguous and sel.flip == 3
    assert [t["index"] for t in sel.top_k] == [0, 1, 2, 3]


def test_near_equal_180_degree_flip_is_flagged_ambiguous():
    sel = select_hypothesis(*hyps([0.10, 0.30, 0.40, 0.105]))
    assert sel.index == 0 and sel.ambiguous and sel.flip == 3
    assert sel.confidence == pytest.approx(0.005 / 0.105)
    assert sel.runner_up_angle_deg == pytest.approx(180.0, abs=1e-6)


def test_symmetric_category_ignores_rotations_about_the_axis():
    R = np.stack([np.eye(3), rot([0, 0, 1], 90), rot([1, 0, 0], 90)])
    s = np.array([0.10, 0.101, 0.20])
    assert select_hypothesis(R, np.zeros((3, 3)), s).confidence == pytest.approx(0.001 / 0.101)
    sel = select_hypothesis(R, np.zeros((3, 3)), s, symmetry="continuous:z")
    assert sel.runner_up == 2 and sel.confidence == pytest.approx(0.5)
    d = symmetric_distance_deg(np.eye(3), R, "discrete:z4")
    np.testing.assert_allclose(d, [0, 0, 90], atol=1e-6)


def test_canonicalised_rotation_is_invariant_under_the_symmetry():
    R = Rotation.from_euler("xyz", [20, -35, 50], degrees=True).as_matrix()
    a = canonicalise_rotation(R, "continuous:z")
    b = canonicalise_rotation(R @ rot([0, 0, 1], 73), "continuous:z")
    np.testing.assert_allclose(a, b, atol=1e-9)
    np.testing.assert_allclose(a[:, 2], R[:, 2], atol=1e-12)                    # the symmetry axis is kept
    np.testing.assert_allclose(a @ a.T, np.eye(3), atol=1e-9)
    assert np.linalg.det(a) == pytest.approx(1.0)
    np.testing.assert_allclose(canonicalise_rotation(R, "discrete:z2"),
                               canonicalise_rotation(R @ rot([0, 0, 1], 180), "discrete:z2"), atol=1e-9)


def test_prefer_keeps_the_previous_hypothesis_within_the_margin():
    R, t, s = hyps([0.100, 0.30, 0.102, 0.50])
    assert select_hypothesis(R, t, s).index == 0
    assert select_hypothesis(R, t, s, prefer=rot([1, 0, 0], 85), prefer_margin=0.05).index == 2
    assert select_hypothesis(R, t, s, prefer=rot([1, 0, 0], 85), prefer_margin=0.01).index == 0


def test_calibration_preserves_the_posed_shape():
    rng = np.random.default_rng(1)
    R_pred = Rotation.random(5, random_state=2).as_matrix()
    t_pred = rng.normal(size=(5, 3))
    dR = Rotation.random(random_state=3).as_matrix()
    dt = rng.normal(size=3)
    R_cat, t_cat = apply_calibration(R_pred, t_pred, dR, dt)
    np.testing.assert_allclose(R_cat, R_pred @ dR.T)
    c = rng.normal(size=(10, 3))                                                # canonical shape (learned frame)
    c_cat = c @ dR.T + dt                                                       # the same shape, category frame
    for j in range(5):
        np.testing.assert_allclose(c_cat @ R_cat[j].T + t_cat[j], c @ R_pred[j].T + t_pred[j], atol=1e-12)
