"""Rotated input copies (test-time rotation augmentation) and their consensus pose.

The network is exactly equivariant only to the 60 icosahedral rotations; between them its hypotheses carry a residual
error that changes with the input's orientation, and its canonical shape (the invariant branch) a little noise. One
object's points are therefore run as ``K`` copies, each turned by a fixed rotation ``Q_k`` about its centroid, in the
same batch; undoing the turns gives ``K`` estimates of one pose and ``K`` reconstructions of one canonical shape.
Each copy also draws its own farthest-point sample of the object's points (``copy_samples``), so the copies' errors
from sampling decorrelate too.

Convention:
    Inputs are model units, centred at the centroid (``PreparedPoints.model_points``), so turning about the origin
    turns about the centroid. Copy ``k`` sees ``Q_k @ x``; its hypotheses (R', t') map back as ``R = Q_kᵀ R'``,
    ``t = Q_kᵀ t'``. The canonical shapes live in the learned frame, which a turn of the input leaves unchanged
    (their points correspond one to one), so they are averaged point by point. Copy 0 is the identity (the input as
    it is). Rotations act on column vectors, ``x = R y + t``.

What the copies and their own samples gain: docs/results/models/README.md (v0.12, v0.13).
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import ConfigError, InvalidPointsError
from equipose.core.geometry import farthest_point_orders, nearest_rotation
from equipose.core.metadata import MAX_COPIES
from equipose.runtime.hypotheses import parse_symmetry, symmetric_distance_deg

__all__ = ["copy_rotations", "copy_samples", "copy_batch", "rotate_copies", "undo_copies", "consensus_pose",
           "COPY_SEED", "AGREE_DEG", "MAX_COPIES"]

COPY_SEED = 1          # the copies' rotations are fixed: seeded uniform rotations after the identity
AGREE_DEG = 15.0       # copies whose best hypotheses lie within this of the medoid's support the consensus


def copy_rotations(k: int) -> np.ndarray:
    """[k, 3, 3]: the identity, then ``k - 1`` uniform rotations from a fixed seed (the same on every machine)."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 1 <= k <= MAX_COPIES:
        raise ConfigError(f"copies must be an int in 1..{MAX_COPIES} (rotated input copies per object), got {k!r}")
    from scipy.spatial.transform import Rotation
    rest = Rotation.random(int(k) - 1, random_state=COPY_SEED).as_matrix() if k > 1 else np.zeros((0, 3, 3))
    return np.concatenate([np.eye(3)[None], rest])


def copy_samples(cloud: np.ndarray, first: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Each copy's own farthest-point sample of one object: [K, N, 3] float32 model units (centred).

    Copy 0 keeps ``first`` (the usual input, FPS from the point farthest from the centroid); copy k ≥ 1 runs FPS over
    ``cloud`` [P, 3] from the point nearest to ``0.5 · rms radius · Q_k[2]`` (a fixed interior aim per copy; the
    result does not depend on the point order), so the copies differ in sampling as well as orientation, as the
    training draws did (random FPS starts). Where P ≤ N every sample holds the same points.
    """
    c = np.asarray(cloud, np.float32)
    x0 = np.asarray(first, np.float32)
    Q = np.asarray(rotations, np.float64)
    if c.ndim != 2 or c.shape[1] != 3 or x0.ndim != 2 or x0.shape[1] != 3 or Q.ndim != 3 or Q.shape[1:] != (3, 3):
        raise InvalidPointsError(f"copy_samples needs cloud [P, 3], first [N, 3] and rotations [K, 3, 3], got "
                                 f"{c.shape}, {x0.shape}, {Q.shape}")
    if not len(c):
        raise InvalidPointsError("copy_samples got no points")
    out = np.empty((len(Q),) + x0.shape, np.float32)                           # [K, N, 3]
    out[0] = x0
    if len(Q) > 1:
        c64 = c.astype(np.float64)                                             # [P, 3], centred
        rms = float(np.sqrt(np.mean(np.einsum("ij,ij->i", c64, c64))))
        aims = 0.5 * rms * Q[1:, 2]                                            # [K−1, 3] fixed points inside the cloud
        d2 = ((c64[None] - aims[:, None]) ** 2).sum(-1)                        # [K−1, P]
        starts = d2.argmin(1)                                                  # the object points nearest to them
        out[1:] = c[farthest_point_orders(c, len(x0), starts)]                 # [K−1, N, 3], one FPS loop for all
    return out


def rotate_copies(points: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """Centred model points → [B·K, N, 3] float32, object b's copy k at row b·K + k (``Q_k @ x``). ``points``
    [B, N, 3] (every copy the same points) or [B, K, N, 3] (each copy its own sample, ``copy_samples``)."""
    x = np.asarray(points, np.float64)
    Q = np.asarray(rotations, np.float64)
    if x.ndim == 3 and Q.ndim == 3:                                            # one sample for every copy
        x = np.broadcast_to(x[:, None], (x.shape[0], len(Q)) + x.shape[1:])    # [B, K, N, 3]
    if x.ndim != 4 or x.shape[-1] != 3 or Q.ndim != 3 or Q.shape[1:] != (3, 3) or x.shape[1] != len(Q):
        raise InvalidPointsError(f"rotate_copies needs points [B, N, 3] or [B, K, N, 3] and rotations [K, 3, 3], got "
                                 f"{np.shape(points)}, {Q.shape}")
    out = np.einsum("kij,bknj->bkni", Q, x)                                    # [B, K, N, 3]
    return np.ascontiguousarray(out.reshape(-1, x.shape[2], 3), dtype=np.float32)


def copy_batch(preps, rotations: np.ndarray) -> np.ndarray:
    """The network input of several objects' copies: ``PreparedPoints`` list → [B·K, N, 3] float32, object b's copy
    k (its own sample, turned by ``Q_k``) at row b·K + k. An input without its full cloud samples ``model_points``."""
    return rotate_copies(np.stack([copy_samples(p.model_points if p.cloud is None else p.cloud, p.model_points,
                                                rotations) for p in preps]), rotations)


def undo_copies(rotations: np.ndarray, translations: np.ndarray, copy_rots: np.ndarray) -> tuple:
    """One object's copies' hypotheses back to the input's frame: R [K, A, 3, 3], t [K, A, 3] (model units) →
    (Q_kᵀ R, Q_kᵀ t) as float64, same shapes."""
    R = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    Q = np.asarray(copy_rots, np.float64)
    if R.ndim != 4 or R.shape[2:] != (3, 3) or t.shape != R.shape[:2] + (3,) or Q.shape != (len(R), 3, 3):
        raise InvalidPointsError(f"undo_copies needs R [K, A, 3, 3], t [K, A, 3], Q [K, 3, 3]; got {R.shape}, "
                                 f"{t.shape}, {Q.shape}")
    return np.einsum("kji,kajl->kail", Q, R), np.einsum("kji,kaj->kai", Q, t)


def consensus_pose(rotations: np.ndarray, translations: np.ndarray, symmetry: str = "none",
                   agree_deg: float = AGREE_DEG) -> tuple:
    """Consensus of the copies' best hypotheses. R [K, 3, 3], t [K, 3] (one per copy, the input's frame) →
    (R [3, 3], t [3], support [K] bool).

    The medoid is the copy with the smallest median angle to the others (modulo ``symmetry``); the copies within
    ``agree_deg`` of it support it. Without symmetry the consensus is the chordal mean of the supporters' rotations
    (projected onto SO(3)); a symmetric category keeps the medoid's rotation (its supporters may differ by the free
    turn). The translation is the supporters' mean.
    """
    R = np.asarray(rotations, np.float64)
    t = np.asarray(translations, np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (len(R), 3) or not len(R):
        raise InvalidPointsError(f"consensus_pose needs R [K, 3, 3] and t [K, 3], got {R.shape}, {t.shape}")
    D = np.stack([symmetric_distance_deg(R[i], R, symmetry) for i in range(len(R))])   # [K, K] degrees
    m = int(np.argmin(np.median(D, 1)))
    support = D[m] <= agree_deg                                                # [K], includes the medoid
    kind, _, _ = parse_symmetry(symmetry)
    R_c = nearest_rotation(R[support].sum(0)) if kind == "none" else R[m].copy()
    return R_c, t[support].mean(0), support
