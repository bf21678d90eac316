"""Training losses, apart from the network: the self-supervised min-of-60 chamfer, the axial-symmetry prior and the
distillation loss of a partial-view student against a complete-shape teacher (``equipose.train.fitting.distill``).

Convention: model units (metres / scale), camera frame; ``out`` is ``EquiPoseNet.forward(..., return_aux=True)``:
``hypothesis_scores`` [B, A], ``hypothesis_rotations`` [B, A, 3, 3], ``hypothesis_translations`` [B, A, 3],
``canonical_shape`` [B, M, 3], ``quaternion_norm`` [B, A]. Chamfer terms are mean squared distances (model units²).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from equipose.core.errors import ConfigError
from equipose.train.network.model import squared_distances

__all__ = ["chamfer_min_of_60_loss", "axial_symmetry_loss", "reachable_targets", "view_distance", "distillation_loss"]


def chamfer_min_of_60_loss(out: dict, quat_weight: float = 0.1) -> torch.Tensor:
    """Self-supervised loss: mean over the batch of min over the 60 hypotheses of the chamfer score, plus
    ``quat_weight`` · mean (‖Δq‖ − 1)². No ground truth involved. ``out`` from ``forward(..., return_aux=True)``."""
    rec = out["hypothesis_scores"].min(dim=1).values.mean()
    reg = (out["quaternion_norm"] - 1.0).pow(2).mean()
    return rec + quat_weight * reg


def axial_symmetry_loss(shape: torch.Tensor, rng) -> torch.Tensor:
    """Label-free prior for rotationally symmetric categories: the canonical shape should look the same turned about
    its z axis. Symmetric chamfer (squared distances) between ``shape`` [B, M, 3] and its copy turned by one random
    angle in [45°, 135°] per sample (``rng``: numpy Generator; far from 0° and from the 180° turn that leaves a lying
    cylinder unchanged); mean over the batch. Without it the min-of-60 loss is as happy to put a squat tin's diameter
    on z as its axis (the network learns "longest direction = z")."""
    a = torch.as_tensor(rng.uniform(math.pi / 4, 3 * math.pi / 4, shape.shape[0]), dtype=shape.dtype,
                        device=shape.device)                                          # [B]
    c, s = torch.cos(a), torch.sin(a)
    turned = torch.stack([c[:, None] * shape[..., 0] - s[:, None] * shape[..., 1],
                          s[:, None] * shape[..., 0] + c[:, None] * shape[..., 1], shape[..., 2]], -1)  # [B, M, 3]
    d2 = squared_distances(shape, turned)                                             # [B, M, M]
    return (d2.min(dim=2).values.mean(dim=1) + d2.min(dim=1).values.mean(dim=1)).mean()


@torch.no_grad()
def reachable_targets(anchors: torch.Tensor, rotations: torch.Tensor, max_deg: float) -> torch.Tensor:
    """Per anchor, the rotation on the geodesic from the anchor toward ``rotations`` at most ``max_deg`` away.

    anchors [A, 3, 3], rotations [B, 3, 3] → [B, A, 3, 3] (detached; scipy's rotation vectors are stable near 180°).
    """
    from scipy.spatial.transform import Rotation
    A_np = anchors.detach().cpu().double().numpy()                                   # [A, 3, 3]
    R_np = rotations.detach().cpu().double().numpy()                                 # [B, 3, 3]
    rel = np.einsum("aji,bjk->baik", A_np, R_np)                                      # [B, A, 3, 3] A_aᵀ R*
    rv = Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec()                      # [B·A, 3]
    ang = np.linalg.norm(rv, axis=1, keepdims=True)
    rv *= np.minimum(1.0, np.radians(max_deg) / np.maximum(ang, 1e-12))
    step = Rotation.from_rotvec(rv).as_matrix().reshape(rel.shape)                    # [B, A, 3, 3]
    out = np.einsum("aij,bajk->baik", A_np, step)
    return torch.as_tensor(out, dtype=rotations.dtype, device=rotations.device)


def _chamfer(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Bidirectional chamfer [...] between point sets a [..., M, 3] and b [..., K, 3] (mean squared distances)."""
    d2 = squared_distances(a, b)                                                      # [..., M, K]
    return d2.min(dim=-1).values.mean(dim=-1) + d2.min(dim=-2).values.mean(dim=-1)


def _subset_chamfer(a: torch.Tensor, b: torch.Tensor, stride: int) -> torch.Tensor:
    """Chamfer [...] of a [..., M, 3] and b [..., M, 3] from every ``stride``-th point of each to all of the other.

    Stays blind to symmetries of the dense sets (a subset point finds its partner in the other dense set) at
    2 × M/stride × M distances instead of 2 × M².
    """
    d_ab = squared_distances(a[..., ::stride, :], b).min(dim=-1).values.mean(dim=-1)
    d_ba = squared_distances(b[..., ::stride, :], a).min(dim=-1).values.mean(dim=-1)
    return d_ab + d_ba


def _to_canonical(points: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor) -> torch.Tensor:
    """Camera-frame points [B, N, 3] into the canonical frame of poses [B, 3, 3], [B, 3]: Rᵀ(x − t)."""
    return torch.einsum("bnj,bjk->bnk", points - translations[:, None], rotations)


def view_distance(points: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor,
                  shape: torch.Tensor) -> torch.Tensor:
    """Mean squared distance [] from observed points, carried into the canonical frame by a pose, to a shape.

    points [B, N, 3] (camera frame), rotations [B, 3, 3] (canonical → camera), translations [B, 3], shape [B, M, 3]
    (canonical frame). One direction: a view covers only part of the shape.
    """
    seen = _to_canonical(points, rotations, translations)                               # [B, N, 3]
    return squared_distances(seen, shape).min(dim=-1).values.mean()


def _skew(v: torch.Tensor) -> torch.Tensor:
    """[..., 3] → [..., 3, 3] the cross-product matrix [v]×."""
    zero = torch.zeros_like(v[..., 0])
    return torch.stack([torch.stack([zero, -v[..., 2], v[..., 1]], -1),
                        torch.stack([v[..., 2], zero, -v[..., 0]], -1),
                        torch.stack([-v[..., 1], v[..., 0], zero], -1)], -2)


def icp_drift(points: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor, shape: torch.Tensor,
              iters: int = 10) -> torch.Tensor:
    """How far [B, 6] point-to-point ICP of a view onto a shape moves away from a pose in ``iters`` iterations.

    Convention: points [B, N, 3] camera frame, rotations [B, 3, 3] (canonical → camera), translations [B, 3], shape
    [B, M, 3] canonical frame, model units. The view is carried into the canonical frame, p = Rᵀ(x − t); each
    iteration pairs every p with its nearest shape point q and moves the view rigidly by the Gauss-Newton step of
    Σ ‖p + ω × p + v − q‖² (ω applied exactly, exp([ω]×)) — the one-directional fit the SDK's re-scoring runs.
    Returns the net motion (rotation vector [rad], translation [model units]) of the view: zero where the pose is a
    fixed point. Differentiable in ``shape`` through every iteration's pairs (the pairing itself is not).
    """
    p0 = _to_canonical(points, rotations, translations).detach()                       # [B, N, 3]
    B, N, _ = p0.shape
    eye = torch.eye(3, dtype=p0.dtype)
    R_net, v_net = eye.expand(B, 3, 3), torch.zeros(B, 3, dtype=p0.dtype)              # p = R_net p0 + v_net
    for _ in range(max(1, int(iters))):
        p = torch.einsum("bij,bnj->bni", R_net, p0) + v_net[:, None]                    # [B, N, 3]
        with torch.no_grad():
            nearest = squared_distances(p, shape).argmin(dim=-1)                         # [B, N]
        q = torch.gather(shape, 1, nearest[..., None].expand(-1, -1, 3))               # [B, N, 3]
        J = torch.cat([-_skew(p), eye.expand(B, N, 3, 3)], -1)                          # [B, N, 3, 6] ∂(ω×p + v)
        A = torch.einsum("bnki,bnkj->bij", J, J) + 1e-6 * N * torch.eye(6, dtype=p.dtype)   # [B, 6, 6]
        step = torch.linalg.solve(A, torch.einsum("bnki,bnk->bi", J, q - p))          # [B, 6] (ω, v)
        dR = torch.linalg.matrix_exp(_skew(step[:, :3]))                                # [B, 3, 3]
        R_net = dR @ R_net
        v_net = torch.einsum("bij,bj->bi", dR, v_net) + step[:, 3:]
    cos = ((R_net.diagonal(dim1=1, dim2=2).sum(-1) - 1) / 2).clamp(-1 + 1e-7, 1 - 1e-7)  # [B]
    angle = torch.acos(cos)                                                             # [B] rad
    axis = torch.stack([R_net[:, 2, 1] - R_net[:, 1, 2], R_net[:, 0, 2] - R_net[:, 2, 0],
                        R_net[:, 1, 0] - R_net[:, 0, 1]], -1)                           # [B, 3] = 2 sin θ · axis
    rotvec = axis * (angle / (2 * torch.sin(angle).clamp_min(1e-7)))[:, None]          # [B, 3]
    return torch.cat([rotvec, v_net], 1)


def distillation_loss(out: dict, shapes: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor,
                      anchors: torch.Tensor, symmetric: bool = False, quat_weight: float = 0.1,
                      select_weight: float = 0.0, select_tolerance: float = 1.5, select_deg: float = 10.0,
                      reach_weight: float = 1.0, reach_deg: float = 40.0, pose_points: int = 64,
                      shape_weight: float = 1.0, points: torch.Tensor | None = None,
                      view_weight: float = 0.0, drift_weight: float = 0.0, drift_iters: int = 10,
                      clouds: torch.Tensor | None = None, cloud_weight: float = 0.0) -> tuple:
    """Student loss against teacher targets; returns (loss, parts dict of floats).

    shape: ``shape_weight`` × chamfer(student canonical shape, teacher shape) — pins the student to the teacher's
    frame, and is the template the SDK's ICP re-scoring fits the view to (its precision caps the pose's).
    pose, on the hypothesis of the anchor nearest to the teacher's rotation (its residual can reach the target: θmax
    ≥ the anchors' covering radius): ``symmetric`` — chamfer(teacher shape posed by it, teacher shape posed by the
    teacher), blind to the spin about the axis, which a partial view of a symmetric shape cannot tell; otherwise
    ‖R − R*‖²_F + ‖t − t*‖² (a chamfer is too flat there: a roll-flipped airplane scores lower than a 21°-off upright
    one). A min over the 60 hypotheses instead locks onto such flips (measured: 152° median after 250 steps).
    reach: ``reach_weight`` × the same term averaged over *all* 60 hypotheses, each against the teacher pose clamped
    to within ``reach_deg`` of its own anchor (≥ the anchors' covering radius, 37.4°, so the nearest anchor's target
    is the teacher pose itself). Every hypothesis turns toward the teacher pose, none stays on a symmetric flip of the
    object (a roll-flipped airplane) that the partial-view chamfer score could not tell from the right pose, and each
    target is reachable without stretching the residual quaternion (an unclamped pull fought its norm penalty:
    near-anchor error stuck at 13°).
    view (optional, ``view_weight`` > 0, needs ``points`` [B, N, 3], the student's input in the camera frame): the
    observed points carried into the teacher's canonical frame by the teacher pose, Rᵀ(x − t), and their mean
    squared distance to the student's canonical shape (one direction: the view covers part of the shape). It asks
    the predicted shape to be right where the camera sees the object, which is all the SDK's ICP re-scoring fits
    against, so that the teacher pose is where that fit settles.
    cloud (optional, ``cloud_weight`` > 0, needs ``clouds`` [B, K, 3]: each view's complete training cloud carried
    into the teacher's canonical frame by the teacher's pose, ``distill.canonical_clouds``): the chamfer of the
    student's canonical shape to that cloud — the real surface in the teacher's frame, not the teacher's
    reconstruction of it, which is what limits the SDK's ICP (as a template: the true cloud 0.51° / 1.00 on chair
    views, the teacher's shape 4.28° / 0.568).
    drift (optional, ``drift_weight`` > 0, needs ``points``): the squared length ‖ω‖² + ‖v‖² of the net motion
    ``drift_iters`` ICP iterations of the view onto the student's shape make from the teacher pose (``icp_drift``):
    the view term asks the fit there to be close, this one asks the teacher pose to be where the fit stops.
    select (optional): cross-entropy making the student's own partial-view chamfer score pick a right hypothesis —
    uniform target over the nearest anchor's and those within ``select_deg`` of R* (symmetric: pose chamfer within
    ``select_tolerance`` × the nearest anchor's). ``out`` from ``forward(..., return_aux=True)``; shapes [B, M, 3],
    rotations [B, 3, 3], translations [B, 3], anchors [A, 3, 3]. The symmetric pose chamfers start from a regular
    subset of about ``pose_points`` points of each set (all 60 hypotheses × M² distances dominated the step: cup
    0.42 s per step with an edge-q student).
    """
    S = shapes
    loss_shape = _chamfer(out["canonical_shape"], S).mean()
    R, t = out["hypothesis_rotations"], out["hypothesis_translations"]               # [B, A, 3, 3], [B, A, 3]
    tr = torch.einsum("aij,bij->ba", anchors, rotations)                              # [B, A] trace(Aᵀ R*) ∝ cos
    near = tr.argmax(dim=1)                                                           # [B] nearest anchor
    ar = torch.arange(len(near), device=near.device)
    R_reach = reachable_targets(anchors, rotations, reach_deg)                        # [B, A, 3, 3]
    R_reach[ar, near] = rotations                                                     # the nearest: exactly R*
    if symmetric:
        stride = max(1, -(-S.shape[1] // pose_points))
        posed = torch.einsum("bmj,bakj->bamk", S, R) + t[:, :, None]                  # [B, A, M, 3]
        goal = torch.einsum("bmj,bakj->bamk", S, R_reach) + translations[:, None, None]   # [B, A, M, 3]
        per = _subset_chamfer(posed, goal, stride)                                    # [B, A] vs reachable goals
    else:
        per = ((R - R_reach).pow(2).sum((2, 3)) + (t - translations[:, None]).pow(2).sum(2))   # [B, A]
    loss_pose = per[ar, near].mean()
    loss_reach = per.mean()
    reg = (out["quaternion_norm"] - 1.0).pow(2).mean()
    loss = shape_weight * loss_shape + loss_pose + reach_weight * loss_reach + quat_weight * reg
    parts = {"shape": loss_shape.item(), "pose": loss_pose.item(), "reach": loss_reach.item()}
    if view_weight > 0:
        if points is None:
            raise ConfigError("distillation_loss: view_weight > 0 needs the input points (points=[B, N, 3])")
        loss_view = view_distance(points, rotations, translations, out["canonical_shape"])
        loss = loss + view_weight * loss_view
        parts["view"] = loss_view.item()
    if cloud_weight > 0:
        if clouds is None:
            raise ConfigError("distillation_loss: cloud_weight > 0 needs the canonical clouds (clouds=[B, K, 3])")
        loss_cloud = _chamfer(out["canonical_shape"], clouds).mean()
        loss = loss + cloud_weight * loss_cloud
        parts["cloud"] = loss_cloud.item()
    if drift_weight > 0:
        if points is None:
            raise ConfigError("distillation_loss: drift_weight > 0 needs the input points (points=[B, N, 3])")
        drift = icp_drift(points, rotations, translations, out["canonical_shape"], drift_iters)   # [B, 6]
        loss_drift = drift.pow(2).sum(1).mean()
        loss = loss + drift_weight * loss_drift
        parts["drift"] = loss_drift.item()
    if select_weight > 0:
        if symmetric:                                                                 # pose chamfer vs R* itself
            with torch.no_grad():
                target = S @ rotations.transpose(1, 2) + translations[:, None]        # [B, M, 3]
                c = _subset_chamfer(posed, target[:, None].expand_as(posed), stride)  # [B, A]
            ok = c <= select_tolerance * c[ar, near][:, None] + 1e-9                 # [B, A]
        else:
            cos = (torch.einsum("baij,bij->ba", R.detach(), rotations) - 1) / 2      # [B, A] cos of the angle to R*
            ok = cos >= math.cos(math.radians(select_deg))
        ok[ar, near] = True
        ok = ok.float()
        s = out["hypothesis_scores"]                                                  # [B, A]
        logp = torch.log_softmax(-s / s.detach().std(dim=1, keepdim=True).clamp_min(1e-9), dim=1)
        loss_sel = -(ok * logp).sum(1).div(ok.sum(1)).mean()
        loss = loss + select_weight * loss_sel
        parts["select"] = loss_sel.item()
    return loss, parts
