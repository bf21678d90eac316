"""The compiled order statistics (``equipose.core.order_statistics``) give numpy's values bit for bit: they replace
numpy calls in the crop, the handle zone and the box prompt's surfaces, whose decisions compare against them."""
import numpy as np
import pytest

from equipose.core.order_statistics import median, sorted_median, sorted_percentile, sorted_quantile


@pytest.mark.parametrize("n", [1, 2, 3, 10, 101, 1000])
def test_median_percentile_and_quantile_equal_numpy(rng, n):
    for _ in range(20):
        x = rng.normal(size=n) * rng.uniform(0.01, 100.0)
        if n > 3:
            x[: n // 3] = x[0]                                                   # ties
        s = np.sort(x)
        assert median(x) == np.median(x)
        assert sorted_median(s) == np.median(x)
        for q in (0.0, 2.0, 50.0, 90.0, 95.0, 98.0, 100.0, float(rng.uniform(0, 100))):
            assert sorted_percentile(s, q) == np.percentile(x, q)
        for q in np.r_[np.linspace(0.0, 1.0, 7), rng.uniform(0, 1, 3)]:
            assert sorted_quantile(s, q) == np.quantile(x, q)


def test_median_of_float32_input_is_float64(rng):
    x = rng.normal(size=333).astype(np.float32)
    assert median(x) == np.median(x.astype(np.float64))
