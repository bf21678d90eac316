"""Format-3 and format-4 kernel inputs (``equipose.core.kernel_weights``) against the hat correlation written out
directly and its class sums as one matrix product."""
import numpy as np
import pytest

from equipose.core.errors import InvalidPointsError
from equipose.core.icosahedral import VERTEX_CLASS, kernel_points
from equipose.core.kernel_weights import (CLASS_MATRIX, class_name, kernel_input_names, kernel_inputs, rows_name,
                                          weights_name)
from equipose.core.neighbourhoods import input_name, neighbourhood_specs, neighbourhoods
from equipose.core.presets import LayerSpec, get_preset


def test_kernel_inputs_are_the_hat_correlations_and_feature_rows():
    layers = get_preset("edge-q").layers
    x = (np.random.default_rng(0).normal(size=(2, 256, 3)) * 0.3 + [0.2, -0.1, 1.5]).astype(np.float32)
    nbh = neighbourhoods(x, neighbourhood_specs(layers))
    got = kernel_inputs(x, layers, nbh)
    assert list(got) == [weights_name(0), weights_name(1), rows_name(1), weights_name(2), rows_name(2),
                         weights_name(3), rows_name(3)]
    assert sorted(got) == sorted(kernel_input_names(layers))
    specs = {s.support: s for s in neighbourhood_specs(layers)}
    x64 = x.astype(np.float64)
    for i, L in enumerate(layers):
        idx = nbh[input_name(specs[L.points_in])][:, :L.points_out, :L.neighbours]          # [B, P2, nn]
        assert idx.max() < L.points_in
        d = np.stack([x64[b, idx[b]] - x64[b, :L.points_out, None] for b in range(2)])     # [B, P2, nn, 3]
        kern = kernel_points(13, L.kernel_radius)                                           # [13, 3]
        dist2 = ((d[:, :, None] - kern[None, None, :, None]) ** 2).sum(-1)                  # [B, P2, 13, nn]
        want = np.maximum(0.0, 1.0 - dist2 / L.sigma)
        w = got[weights_name(i)]
        assert w.dtype == np.float32 and w.shape == want.shape
        np.testing.assert_allclose(w, want, atol=2e-5)
        assert (w > 0).any() and (w == 0).any()                                 # both sides of the hat are met
        if i:
            rows = got[rows_name(i)]
            assert rows.dtype == np.int64
            np.testing.assert_array_equal(rows, (idx + np.arange(2)[:, None, None] * L.points_in).reshape(-1))


def test_kernel_inputs_are_translation_invariant_and_check_shapes():
    layers = get_preset("edge-q").layers
    x = (np.random.default_rng(1).normal(size=(1, 256, 3)) * 0.3).astype(np.float32)
    nbh = neighbourhoods(x, neighbourhood_specs(layers))
    a = kernel_inputs(x, layers, nbh)
    b = kernel_inputs(x + np.float32(2.0), layers, nbh)                          # the graph's input is centred
    for k in a:
        np.testing.assert_allclose(a[k], b[k], atol=1e-5)
    with pytest.raises(InvalidPointsError):
        kernel_inputs(x[0], layers, nbh)


def test_class_matrix_counts_each_class_from_each_vertex():
    m = CLASS_MATRIX.reshape(12, 5, 13)
    np.testing.assert_array_equal(m.sum(-1), np.tile([1, 1, 5, 5, 1], (12, 1)))     # centre, same, near, far, anti
    np.testing.assert_array_equal(m.sum(1), np.ones((12, 13)))                     # every kernel point in one class
    for v in range(12):
        for c in range(4):
            np.testing.assert_array_equal(np.flatnonzero(m[v, 1 + c, 1:]), np.flatnonzero(VERTEX_CLASS[v] == c))


@pytest.mark.parametrize("layers", [get_preset("edge-q").layers,
                                    (LayerSpec(1, 4, 60, 45, 0.6, 0.1, 0.3, 6),        # 3 · 45 centres: a last tile
                                     LayerSpec(4, 4, 45, 21, 0.6, 0.1, 0.3, 5))],       # of the kernel not full
                         ids=["edge-q", "odd-sizes"])
def test_class_inputs_are_the_class_sums_of_the_kernel_weights(layers):
    B = 3
    x = (np.random.default_rng(2).normal(size=(B, layers[0].points_in, 3)) * 0.3).astype(np.float32)
    nbh = neighbourhoods(x, neighbourhood_specs(layers))
    plain = kernel_inputs(x, layers, nbh)
    every = tuple(range(len(layers)))
    got = kernel_inputs(x, layers, nbh, classes=every)
    assert list(got) == [class_name(0)] + [n for i in range(1, len(layers)) for n in (class_name(i), rows_name(i))]
    assert sorted(got) == sorted(kernel_input_names(layers, every))
    for i, L in enumerate(layers):
        summed = CLASS_MATRIX.astype(np.float64) @ plain[weights_name(i)]         # [B, P2, 60, nn]
        if i == 0:                                                              # [B, P2, 12, 5]
            want = summed.sum(-1).reshape(B, L.points_out, 12, 5)
        else:                                                                   # [12, B·P2, 5, nn]
            want = summed.reshape(B * L.points_out, 12, 5, L.neighbours).transpose(1, 0, 2, 3)
            np.testing.assert_array_equal(got[rows_name(i)], plain[rows_name(i)])
        c = got[class_name(i)]
        assert c.dtype == np.float32 and c.shape == want.shape
        np.testing.assert_allclose(c, want, atol=2e-5 * L.neighbours)
    mixed = kernel_inputs(x, layers, nbh, classes=(0,))                           # per layer: one or the other
    assert sorted(mixed) == sorted(kernel_input_names(layers, (0,)))
    np.testing.assert_array_equal(mixed[class_name(0)], got[class_name(0)])
    np.testing.assert_array_equal(mixed[weights_name(1)], plain[weights_name(1)])
