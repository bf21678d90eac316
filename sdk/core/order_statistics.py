"""Medians and percentiles equal to numpy's defaults (linear interpolation), compiled for small arrays inside numba
kernels and for per-frame statistics where numpy's call overhead (20–60 µs) would dominate.

Convention: 1-D float arrays; ``q`` in percent [0, 100].
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["median", "sorted_percentile", "sorted_quantile", "sorted_median", "selected_percentile"]


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
    return _between(sorted_values[lo], sorted_values[hi], v - lo)


@njit(cache=True)
def selected_percentile(values, q):
    """``sorted_percentile(np.sort(values), q)`` of ``values`` [n ≥ 1] from the two order statistics it needs, found
    by selection instead of a full sort (the same value, in O(n))."""
    n = len(values)
    v = (n - 1) * (q / 100.0)
    lo = int(np.floor(v))
    part = np.partition(values, lo)
    return _between(part[lo], part[lo + 1:].min() if lo + 1 < n else part[lo], v - lo)


@njit(cache=True)
def _between(a, b, gamma):
    """numpy's linear interpolation from order statistic ``a`` to the next one ``b`` by ``gamma`` in [0, 1)."""
    return b - (b - a) * (1.0 - gamma) if gamma >= 0.5 else a + (b - a) * gamma
