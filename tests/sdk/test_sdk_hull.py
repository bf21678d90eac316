"""The compiled quickhull (equipose.core.hull) against qhull, and hidden point removal on top of it."""
import numpy as np
import pytest
from scipy.spatial import ConvexHull

from equipose.core.hull import hull_vertex_mask
from equipose.errors import InvalidPointsError
from equipose.runtime.visibility import visible_mask


def _qhull_mask(points):
    mask = np.zeros(len(points), bool)
    mask[ConvexHull(points).vertices] = True
    return mask


def _flipped(points, camera, exponent=1.0):
    d = points - camera
    r = np.linalg.norm(d, axis=1, keepdims=True)
    return np.vstack([d + 2.0 * (r.max() * 10.0 ** exponent - r) * d / r, np.zeros((1, 3))])


@pytest.mark.parametrize("n", [4, 5, 12, 60, 300, 1500])
def test_vertices_match_qhull_on_random_sets(rng, n):
    for _ in range(5):
        p = rng.normal(size=(n, 3)) * [1.0, 0.3, 2.0]
        mask, status = hull_vertex_mask(p)
        assert status == "ok" and np.array_equal(mask, _qhull_mask(p))



@pytest.mark.parametrize("axes", [(1.0, 1.0, 1e-4), (1e3, 1e-2, 1.0)])
def test_vertices_match_qhull_on_thin_and_stretched_sets(rng, axes):
    for _ in range(20):
        p = rng.normal(size=(int(rng.integers(20, 600)), 3)) * axes
        mask, status = hull_vertex_mask(p)
        assert status == "ok" and np.array_equal(mask, _qhull_mask(p))

def test_every_point_on_a_sphere_is_a_vertex(rng, monkeypatch):
    """All N points on the hull; with 2 facets per point allotted the first pass runs out of room and the retry
    (4× the room) finishes it."""
    import equipose.core.hull as hull

    p = rng.normal(size=(800, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    mask, status = hull_vertex_mask(p)
    assert status == "ok" and mask.all()
    assert hull._quickhull(p, hull.HULL_EPS, np.zeros(800, bool), 2 * 800 + 64) == hull._FULL
    monkeypatch.setattr(hull, "ROOM", 2)
    mask, status = hull_vertex_mask(p)
    assert status == "ok" and mask.all()


def test_hidden_point_removal_sets_match_qhull(rng):
    """The spherical flips of the view stage: a template of 256 points seen from 5–10 radii away."""
    for _ in range(20):
        y = rng.normal(size=(256, 3)) * [1.0, 0.5, 0.3]
        camera = rng.normal(size=3)
        camera *= rng.uniform(5, 10) / np.linalg.norm(camera)
        f = _flipped(y, camera)
        mask, status = hull_vertex_mask(f)
        assert status == "ok" and np.array_equal(mask, _qhull_mask(f))
        assert np.array_equal(visible_mask(y, camera), mask[:256])


def test_flat_and_tiny_sets(rng):
    plane = np.c_[rng.normal(size=(50, 2)), np.zeros(50)]
    assert hull_vertex_mask(plane)[1] == "flat"
    assert hull_vertex_mask(np.zeros((10, 3)))[1] == "flat"
    assert hull_vertex_mask(rng.normal(size=(3, 3)))[1] == "flat"
    assert visible_mask(plane, np.array([0.0, 0.0, 5.0])).all()              # flat: nothing is claimed hidden


def test_bad_input():
    with pytest.raises(InvalidPointsError):
        hull_vertex_mask(np.zeros((5, 2)))
    bad = np.ones((6, 3))
    bad[2, 1] = np.nan
    with pytest.raises(InvalidPointsError, match="NaN"):
        hull_vertex_mask(bad)
