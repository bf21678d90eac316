"""Format-3 kernel inputs (``equipose.core.kernel_weights``) against the hat correlation written out directly."""
import numpy as np
import pytest

from equipose.core.errors import InvalidPointsError
from equipose.core.icosahedral import kernel_points
from equipose.core.kernel_weights import kernel_input_names, kernel_inputs, rows_name, weights_name
from equipose.core.neighbourhoods import input_name, neighbourhood_specs, neighbourhoods
from equipose.core.presets import get_preset


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
