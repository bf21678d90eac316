"""The logistic models the model files store (``confidence_calibration``, ``flip_risk``): an entry {"features":
[name, ...], "weights" [F], "bias"} gives the probability σ(bias + Σ weight·feature) of what it was fitted for.

Convention: features by name (unitless as their stages define them); probabilities in [0, 1].
"""
from __future__ import annotations

import numpy as np

__all__ = ["logistic", "entry_probability"]


def logistic(z):
    """σ(z) = 1 / (1 + e^−z), z clipped to ±60 (scalar or array)."""
    return 1.0 / (1.0 + np.exp(-np.clip(z, -60.0, 60.0)))


def entry_probability(entry: dict, values: dict) -> float:
    """σ(bias + Σ weight·feature) of a logistic ``entry`` on ``values`` ({feature name: float})."""
    z = entry["bias"] + float(np.dot(entry["weights"], [values[f] for f in entry["features"]]))
    return float(logistic(z))
