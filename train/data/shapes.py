"""Procedural training shapes: closed cylinders (cans, tins, tubes) of any proportion.

Convention:
    Object frame: the symmetry axis is +z, the origin is the cylinder's centre (half the height above the base);
    units are whatever ``radius`` and ``height`` are given in (metres for the tabletop data). ModelNet's bottles are
    nearly all taller than wide; these fill in the squat end (cookie tins, tuna cans, lids), so that a model of the
    ``can`` category cannot take "the longest direction" for the symmetry axis.
"""
from __future__ import annotations

import numpy as np

__all__ = ["cylinder_surface", "cylinder_mesh", "cylinder_proportions"]


def cylinder_surface(radius: float, height: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points uniform on the closed surface (side + both caps), by area. Returns [n, 3] in the object frame."""
    side, cap = 2.0 * np.pi * radius * height, np.pi * radius ** 2
    part = rng.choice(3, size=n, p=np.array([side, cap, cap]) / (side + 2.0 * cap))   # [n] 0 side, 1 top, 2 bottom
    theta = rng.uniform(0.0, 2.0 * np.pi, n)                                           # [n]
    rho = np.where(part == 0, radius, radius * np.sqrt(rng.uniform(0.0, 1.0, n)))      # [n] uniform on a disc
    z = np.where(part == 0, rng.uniform(-height / 2, height / 2, n), np.where(part == 1, height / 2, -height / 2))
    return np.stack([rho * np.cos(theta), rho * np.sin(theta), z], axis=1)


def cylinder_mesh(radius: float, height: float, segments: int = 48) -> tuple:
    """Closed triangle mesh (outward-facing). Returns (vertices [2·segments + 2, 3], faces [4·segments, 3] int)."""
    a = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)                        # [S]
    ring = np.stack([radius * np.cos(a), radius * np.sin(a)], axis=1)                  # [S, 2]
    top = np.concatenate([ring, np.full((segments, 1), height / 2)], 1)                # [S, 3]
    bottom = np.concatenate([ring, np.full((segments, 1), -height / 2)], 1)            # [S, 3]
    V = np.concatenate([top, bottom, [[0.0, 0.0, height / 2], [0.0, 0.0, -height / 2]]])   # [2S + 2, 3]
    i = np.arange(segments)
    j = (i + 1) % segments
    ct, cb = 2 * segments, 2 * segments + 1
    F = np.concatenate([np.stack([i, segments + i, j], 1), np.stack([j, segments + i, segments + j], 1),  # side
                        np.stack([np.full(segments, ct), i, j], 1),                                     # top cap
                        np.stack([np.full(segments, cb), segments + j, segments + i], 1)])              # bottom cap
    return V, F.astype(np.int64)


def cylinder_proportions(count: int, seed, radius: tuple = (0.03, 0.07), aspect: tuple = (0.25, 4.0)) -> np.ndarray:
    """``count`` seeded (radius, height) pairs: radius uniform in ``radius``, height / diameter log-uniform in
    ``aspect`` (half of them squatter than wide for the default range). Returns [count, 2]."""
    rng = np.random.default_rng(seed)
    r = rng.uniform(*radius, count)
    hd = np.exp(rng.uniform(np.log(aspect[0]), np.log(aspect[1]), count))
    return np.stack([r, hd * 2.0 * r], axis=1)
