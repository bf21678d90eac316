"""The denser ICP template (equipose.runtime.template) and PoseEstimator(densify=...)."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from equipose.errors import ConfigError, InvalidPointsError
from equipose.runtime.template import densify_template


def test_densify_adds_each_neighbour_midpoint_once():
    g = np.arange(5.0)
    line = np.c_[g, np.zeros(5), np.zeros(5)]                                # 5 points 1 apart on x
    assert np.array_equal(densify_template(line, 0), line)
    one = densify_template(line, 1)                                          # the 4 gaps, each once
    assert len(one) == 9 and np.array_equal(one[:5], line)
    assert sorted(one[5:, 0]) == [0.5, 1.5, 2.5, 3.5]
    two = densify_template(line, 2)          # + the ends' second neighbours (0–2, 2–4); inner points' are the gaps
    assert len(two) == 5 + 4 + 2 and set(two[5:, 0]) == {0.5, 1.0, 1.5, 2.5, 3.0, 3.5}


def test_densify_fills_the_surface_between_points():
    """On a sphere of 256 points the midpoints bring any surface point closer to the template (by about a quarter)."""
    rng = np.random.default_rng(0)
    y = rng.normal(size=(256, 3))
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    q = rng.normal(size=(4000, 3))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    dense = densify_template(y, 4)
    assert 2.0 * len(y) < len(dense) < 5 * len(y)
    gap0, gap4 = cKDTree(y).query(q)[0].mean(), cKDTree(dense).query(q)[0].mean()
    assert gap4 < 0.8 * gap0                                                 # 0.77 measured
    with_dupes = densify_template(np.concatenate([y[:10], y[:10]]), 3)       # repeated points: no zero-length pairs
    assert np.isfinite(with_dupes).all() and len(with_dupes) > 20


def test_densify_midpoints_in_pair_order():
    """The midpoints follow the pairs (low index, high index) in lexicographic order, each pair once."""
    rng = np.random.default_rng(2)
    y = rng.normal(size=(64, 3))
    y[9] = y[3]                                          # a duplicate: the tree may list a point as its own neighbour
    _, nn = cKDTree(y).query(y, 4)
    pairs = sorted({(min(i, int(j)), max(i, int(j))) for i in range(64) for j in nn[i, 1:] if j != i})
    expected = np.array([(y[a] + y[b]) / 2 for a, b in pairs])
    dense = densify_template(y, 3)
    assert np.array_equal(dense[:64], y) and np.array_equal(dense[64:], expected)

@pytest.mark.parametrize("size, k", [(7, 2), (256, 4), (300, 16)])
def test_densify_brute_force_matches_the_tree(monkeypatch, size, k):
    """Templates up to BRUTE_MAX_TEMPLATE points find their neighbours by compiled brute force; the k-d tree that
    larger ones use gives the same template, point for point."""
    import equipose.runtime.template as template
    y = np.random.default_rng(size).normal(size=(size, 3)).astype(np.float32)
    brute = densify_template(y, k)
    monkeypatch.setattr(template, "BRUTE_MAX_TEMPLATE", 0)
    assert np.array_equal(brute, densify_template(y, k))


def test_densify_rejects_bad_input():
    for bad in (np.zeros((4, 2)), np.zeros(3)):
        with pytest.raises(InvalidPointsError):
            densify_template(bad, 2)
    for k in (-1, 17, 1.5, True):
        with pytest.raises(ConfigError, match="densify"):
            densify_template(np.zeros((4, 3)), k)


def test_estimator_densify_option(tiny_model):
    """densify: the re-scoring and its ICP use the denser template; it needs the re-scoring."""
    from equipose import PoseEstimator
    pts = np.random.default_rng(1).normal(scale=0.05, size=(400, 3)) + [0.0, 0.0, 0.8]
    base = PoseEstimator(tiny_model, threads=1, refine=3)
    est = PoseEstimator(tiny_model, threads=1, refine=3, densify=4)
    assert base.densify == 0 and est.densify == 4
    r = est.predict_points(pts)
    assert np.allclose(r.rotation @ r.rotation.T, np.eye(3), atol=1e-6) and np.isfinite(r.translation).all()
    assert len(r.canonical_shape_object) == len(base.predict_points(pts).canonical_shape_object)  # the shape reported
    for bad in (-1, 17, 1.5, True, "more"):
        with pytest.raises(ConfigError, match="densify"):
            PoseEstimator(tiny_model, threads=1, refine=3, densify=bad)
    with pytest.raises(ConfigError, match="refine"):
        PoseEstimator(tiny_model, threads=1, refine=0, densify=4)
