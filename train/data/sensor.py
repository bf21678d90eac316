"""A structured-light / stereo depth-sensor model applied to clean rendered depth: what a real tabletop camera adds.

Convention:
    Depth frames are [H, W] float64 metres with ``inf`` (or 0) = no return, OpenCV camera (z forward). The model,
    in order: axial noise N(0, σ(z)²) with σ(z) = a + b·(z − z₀)² (a Kinect-class sensor: a = 1.2 mm, b = 1.9 mm/m²,
    z₀ = 0.4 m, Nguyen et al. 2012); flying pixels at depth edges (a pixel next to a jump larger than ``edge_jump``
    takes a value between the two surfaces with probability ``flying``); holes at edges (``edge_dropout``) and
    anywhere (``dropout``); quantisation to the sensor's step (1 mm, like a uint16 millimetre frame). All draws come
    from the given generator, so a seed reproduces a frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SensorModel", "apply_sensor"]


@dataclass(frozen=True)
class SensorModel:
    """Parameters of ``apply_sensor`` (metres, probabilities per pixel)."""
    sigma_a: float = 0.0012        # axial noise at z0 (m)
    sigma_b: float = 0.0019        # growth of the axial noise (m per m²)
    z0: float = 0.4                # depth of the smallest noise (m)
    edge_jump: float = 0.02        # a neighbour this much nearer/farther makes a pixel an edge pixel (m)
    flying: float = 0.4            # chance that an edge pixel returns a depth between the two surfaces
    edge_dropout: float = 0.25     # chance that an edge pixel returns nothing
    dropout: float = 0.01          # chance that any pixel returns nothing
    step: float = 0.001            # quantisation step (m)


def _edge_pixels(d: np.ndarray, jump: float) -> tuple:
    """(edge [H, W] bool, the far/near depth of the largest jump to a 4-neighbour [H, W]) of a depth frame."""
    z = np.where(np.isfinite(d) & (d > 0), d, np.nan)                          # [H, W]
    other = np.full_like(z, np.nan)
    best = np.zeros_like(z)
    for axis, shift in ((0, 1), (0, -1), (1, 1), (1, -1)):
        nb = np.roll(z, shift, axis=axis)
        gap = np.abs(np.nan_to_num(nb - z, nan=0.0))                           # [H, W] missing neighbours: no jump
        take = gap > best
        best = np.where(take, gap, best)
        other = np.where(take, nb, other)
    return best > jump, other


def apply_sensor(depth_m: np.ndarray, rng: np.random.Generator, model: SensorModel | None = None) -> np.ndarray:
    """Clean rendered depth → what the sensor would return.

    Convention: ``depth_m`` [H, W] metres (inf or ≤ 0 = no return) → [H, W] float64 metres, 0 = no return.
    """
    m = model or SensorModel()
    d = np.asarray(depth_m, np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth must be [H, W], got {d.shape}")
    valid = np.isfinite(d) & (d > 0)                                            # [H, W]
    edge, other = _edge_pixels(d, m.edge_jump)                                  # [H, W], [H, W]
    out = np.where(valid, d, 0.0)
    sigma = m.sigma_a + m.sigma_b * (out - m.z0) ** 2                           # [H, W] m
    out = out + valid * rng.normal(size=d.shape) * sigma
    u = rng.random(d.shape)                                                     # one draw decides an edge pixel's fate
    fly = valid & edge & np.isfinite(other) & (u < m.flying)
    mix = rng.random(d.shape)
    out = np.where(fly, out + mix * (np.nan_to_num(other) - out), out)         # between the two surfaces
    hole = (valid & edge & (u >= m.flying) & (u < m.flying + m.edge_dropout)) | (rng.random(d.shape) < m.dropout)
    out[hole] = 0.0
    out = np.round(out / m.step) * m.step
    out[~valid] = 0.0
    return out
