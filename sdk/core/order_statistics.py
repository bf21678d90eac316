"""Medians and percentiles equal to numpy's defaults (linear interpolation), compiled for small arrays inside numba
kernels and for per-frame statistics where numpy's call overhead (20–60 µs) would dominate.

Convention: 1-D float arrays; ``q`` in percent [0, 100].
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["median", "sorted_percentile", "sorted_quantile", "sorted_median"]


def median(values: np.ndarray) -> float:
    """``np.median(values)`` of ``values`` [n] (n ≥ 1), computed in float64."""
    return float(sorted_median(np.sort(np.ascontiguousarray(values, np.float64))))


@njit(cache=True)
def sorted_median(sorted_values):
    """numpy's median of ascending ``sorted_values`` [n], n ≥ 1."""
    n = len(sorted_values)
    return sorted_values[n // 2] if n % 2 else (sorted_values[n // 2 - 1] + sorted_values[n // 2]) / 2.0


@njit(cache=True)
def sorted_percentile(sorted_values, q):
    """numpy's default (linear) percentile ``q`` of ascending ``sorted_values`` [n], n ≥ 1."""
    return sorted_quantile(sorted_values, q / 100.0)


@njit(cache=True)
def sorted_quantile(sorted_values, q):
    """numpy's default (linear) quantile ``q`` in [0, 1] of ascending ``sorted_values`` [n], n ≥ 1."""
    v = (len(sorted_values) - 1) * q
    lo = int(np.floor(v))
    hi = min(lo + 1, len(sorted_values) - 1)
    gamma = v - lo
    a, b = sorted_values[lo], sorted_values[hi]
    return b - (b - a) * (1.0 - gamma) if gamma >= 0.5 else a + (b - a) * gamma
