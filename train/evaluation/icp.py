"""ICP-60 + template baseline (the paper's "ICP + template shape"): point-to-point ICP from the 60 icosahedral
rotations, best final residual wins.

Convention:
    ``observed`` [N, 3] and ``template`` [M, 3] in the same units (metres or model units); the template is in the
    category frame. Result (R [3, 3], t [3]) maps the template into the observation: x ≈ R @ y + t (column vectors),
    i.e. the same pose convention as the network. All 60 initialisations run in the SDK's compiled ICP
    (``equipose.core.icp``: exact nearest neighbours from k-d trees, closed-form rotation updates).
    ``bidirectional`` (complete shapes) adds template→observation correspondences; partial observations use only
    observation→template, as a partial view covers part of the template.
"""
from __future__ import annotations

import numpy as np

from equipose.core import icosahedral
from equipose.core.errors import InvalidPointsError
from equipose.runtime.refine import icp_multi, kabsch  # noqa: F401  (re-exported; the ICP core lives in the SDK)

__all__ = ["kabsch", "icp_multi", "icp60_all", "icp60", "icp60_outputs"]


def icp60_all(observed: np.ndarray, template: np.ndarray, iters: int = 30, bidirectional: bool = False) -> tuple:
    """All 60 ICP runs started at the icosahedral rotations (translation: centroid alignment).

    Returns (R [60, 3, 3], t [60, 3], residual [60]) in anchor order.
    """
    x, y = np.asarray(observed, np.float64), np.asarray(template, np.float64)
    A = icosahedral.ANCHORS.astype(np.float64)                                 # [60, 3, 3]
    t0 = x.mean(0)[None] - np.einsum("jik,k->ji", A, y.mean(0))               # [60, 3]
    return icp_multi(x, y, A, t0, iters=iters, bidirectional=bidirectional)


def icp60(observed: np.ndarray, template: np.ndarray, iters: int = 30, bidirectional: bool = False) -> tuple:
    """Best of the 60 ICP runs of ``icp60_all`` (lowest final residual). Returns (R [3, 3], t [3], residual float)."""
    R, t, res = icp60_all(observed, template, iters=iters, bidirectional=bidirectional)
    j = int(np.argmin(res))
    return R[j], t[j], float(res[j])


def icp60_outputs(model_points: np.ndarray, template: np.ndarray, iters: int = 30, bidirectional: bool = False) -> dict:
    """ICP-60 in the network's output contract, so the SDK's selection and calibration apply unchanged.

    Convention: ``model_points`` [B, N, 3] model units; ``template`` [M, 3] in the frame the hypotheses refer to (the
    network's learned frame when it is the model's own canonical shape). Returns numpy ``hypothesis_rotations``
    [B, 60, 3, 3], ``hypothesis_translations`` [B, 60, 3], ``hypothesis_scores`` [B, 60] (final residual; lower is
    better, as the chamfer scores) and ``canonical_shape`` [B, M, 3] (the template).
    """
    x = np.asarray(model_points, np.float64)
    if x.ndim != 3 or x.shape[-1] != 3:
        raise InvalidPointsError(f"ICP-60 outputs need model points [B, N, 3], got {x.shape}")
    y = np.asarray(template, np.float64)
    Rs, ts, rs = [], [], []
    for xb in x:
        R, t, res = icp60_all(xb, y, iters=iters, bidirectional=bidirectional)
        Rs.append(R)
        ts.append(t)
        rs.append(res)
    return {"hypothesis_rotations": np.stack(Rs).astype(np.float32),
            "hypothesis_translations": np.stack(ts).astype(np.float32),
            "hypothesis_scores": np.stack(rs).astype(np.float32),
            "canonical_shape": np.broadcast_to(y.astype(np.float32), (len(x),) + y.shape).copy()}
