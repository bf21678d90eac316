"""What the runtime computes around a format-2 graph: the network's neighbourhoods and the hypothesis scores
(``equipose.core.neighbourhoods``, ``equipose.core.scores``), against plain numpy."""
import numpy as np
import pytest

from equipose.core.errors import InvalidPointsError
from equipose.core.neighbourhoods import (NeighbourhoodSpec, input_name, nearest_neighbourhoods, neighbourhood_specs,
                                          neighbourhoods)
from equipose.core.presets import get_preset
from equipose.core.scores import hypothesis_scores


def _squared(a, b):
    return ((a[..., :, None, :] - b[..., None, :, :]) ** 2).sum(-1)            # [..., P, Q]


def test_neighbourhoods_are_the_k_nearest_nearest_first():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(3, 200, 3)).astype(np.float32)
    spec = NeighbourhoodSpec(support=150, centres=40, k=9, ordered=True)
    got = nearest_neighbourhoods(x, spec)                                       # [3, 40, 9]
    d = _squared(x[:, :40].astype(np.float64), x[:, :150].astype(np.float64))  # [3, 40, 150]
    want = np.argsort(d, axis=-1, kind="stable")[..., :9]
    assert got.dtype == np.int64 and got.shape == (3, 40, 9)
    np.testing.assert_array_equal(got, want)
    assert (got[..., 0] == np.arange(40)).all()                                 # each centre is its own nearest


def test_neighbourhood_ties_go_to_the_lower_index():
    x = np.zeros((1, 6, 3), np.float32)
    x[0, 1:, 0] = [1.0, -1.0, 1.0, 2.0, -1.0]                                   # 1, 2, 3, 5 tie at distance 1
    got = nearest_neighbourhoods(x, NeighbourhoodSpec(support=6, centres=1, k=4, ordered=True))
    np.testing.assert_array_equal(got[0, 0], [0, 1, 2, 3])


def test_specs_share_one_neighbourhood_per_support():
    cfg = get_preset("edge-q")
    specs = neighbourhood_specs(cfg.layers)
    assert [s.support for s in specs] == list(dict.fromkeys(L.points_in for L in cfg.layers))
    for s in specs:
        users = [L for L in cfg.layers if L.points_in == s.support]
        assert s.centres == max(L.points_out for L in users) and s.k == max(L.neighbours for L in users)
        assert s.ordered == any(L.neighbours < s.k for L in users)
    x = np.random.default_rng(1).normal(size=(2, cfg.num_points, 3)).astype(np.float32)
    feeds = neighbourhoods(x, specs)
    assert list(feeds) == [input_name(s) for s in specs] == [f"neighbours_{s.support}" for s in specs]
    with pytest.raises(InvalidPointsError):
        nearest_neighbourhoods(x[:, :10], specs[0])


@pytest.mark.parametrize("bidirectional", [False, True])
def test_hypothesis_scores_match_a_numpy_chamfer(bidirectional):
    rng = np.random.default_rng(2)
    x = rng.normal(size=(2, 100, 3)).astype(np.float32) * 0.3                 # [B, N, 3]
    shape = rng.normal(size=(2, 64, 3)).astype(np.float32) * 0.3              # [B, M, 3]
    q = rng.normal(size=(2, 7, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    w, a, b, c = np.moveaxis(q, -1, 0)
    R = np.stack([1 - 2 * (b * b + c * c), 2 * (a * b - w * c), 2 * (a * c + w * b),
                  2 * (a * b + w * c), 1 - 2 * (a * a + c * c), 2 * (b * c - w * a),
                  2 * (a * c - w * b), 2 * (b * c + w * a), 1 - 2 * (a * a + b * b)], -1).reshape(2, 7, 3, 3)
    t = rng.normal(size=(2, 7, 3)) * 0.05
    got = hypothesis_scores(x, shape, R, t, bidirectional=bidirectional, score_points=80)   # [2, 7]
    posed = np.einsum("bjik,bmk->bjmi", R, shape.astype(np.float64)) + t[:, :, None]      # [B, J, M, 3]
    d = _squared(x[:, None, :80].astype(np.float64), posed)                    # [B, J, 80, M]
    want = d.min(-1).mean(-1) + (d.min(-2).mean(-1) if bidirectional else 0.0)
    assert got.shape == (2, 7) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-7)
    with pytest.raises(InvalidPointsError):
        hypothesis_scores(x, shape, R[:, :, :2], t, bidirectional=bidirectional)
