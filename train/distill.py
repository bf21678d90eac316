"""Partial-view training distilled from a trained complete-shape model (a measured deviation from the paper).

The paper trains the partial model with the one-directional min-of-60 chamfer from the partial points to the
predicted canonical shape. On a CPU budget that loss did not converge (airplane: 153° median after 3k steps) and on
squat categories it collapses the canonical shape into a round blob (cup: isotropy 0.94), because a blob explains
every partial view. Here a complete-shape model of the same category — itself trained without pose labels — is the
teacher: for every rendered view it sees the *complete* cloud in the same pose and gives a pose and a canonical shape
in its own learned frame. No ground-truth pose or canonical frame enters the loss; the renderer's pose is used only to
place the complete cloud where the partial view came from (the same known augmentation the complete-shape training
applies), and the student's frame is the teacher's learned frame (calibrated afterwards like any model).

Convention:
    Model units (metres / scale), camera frame. Teacher targets per view: ``rotations`` [V, 3, 3] (canonical →
    camera), ``translations`` [V, 3] (the complete cloud's centroid), ``shapes`` [V, M, 3] (teacher's canonical shape,
    centred at the origin). Loss terms are chamfer distances (mean squared, model units²).
"""
from __future__ import annotations

import json
import math
import pathlib

import numpy as np
import torch
from tqdm import tqdm

from equipose.errors import ConfigError

from .checkpoint import model_from_checkpoint
from .model import squared_distances

__all__ = ["complete_clouds", "teacher_targets", "distillation_loss"]


def complete_clouds(root, category: str, split: str, limit: int | None = None) -> list:
    """Complete point clouds [P_i, 3] per instance, in the frame and units (metres) the render cache posed them in."""
    from .tabletop import is_tabletop, tabletop_sources
    if is_tabletop(category):
        return [np.asarray(c, np.float64) for _, _, c in tabletop_sources(root, category, split)[:limit]]
    from .render import _modelnet_shapes
    return [np.asarray(c, np.float64) for _, _, c in _modelnet_shapes(root, category, split, "npy1024", limit)]


@torch.no_grad()
def teacher_targets(teacher_path, dataset, clouds: list, refine: int = 5, batch_size: int = 32,
                    cache_file=None, log=print) -> dict:
    """Teacher pose for every view of ``dataset`` (a ``RenderedPartial``) and canonical shape for every instance.

    Returns ``{"rotations" [V, 3, 3], "translations" [V, 3] (model units, camera frame of each view),
    "shapes" [I, M, 3] (one per instance), "instance" [V] int64 (each view's row of "shapes")}``.

    The teacher sees each instance's complete cloud once, in the object frame the renderer posed it from; its pose
    is carried to every view by that view's render pose (R_view · R_teacher, R_view · c + t_view) — exact for the
    ICP-refined pose, and every view of an instance shares one frame. ``refine`` > 0: the teacher's ``refine`` best
    hypotheses are ICP-refined against its own canonical shape and re-ranked (``equipose.refine``), as the shipped
    complete models run. Cached in ``cache_file`` (keyed by the teacher file, the views and ``refine``).
    """
    from equipose.geometry import farthest_point_order
    from equipose.refine import refine_hypotheses
    teacher, ck = model_from_checkpoint(teacher_path)
    if teacher.partial:
        raise ConfigError(f"--teacher {teacher_path}: the teacher must be a complete-shape model (mode complete)")
    key = json.dumps({"teacher": str(pathlib.Path(teacher_path).resolve()), "teacher_step": ck.get("step"),
                      "views": len(dataset), "instances": len(clouds), "refine": refine, "v": 3})
    if cache_file is not None and pathlib.Path(cache_file).is_file():
        z = np.load(cache_file)
        if str(z["key"]) == key:
            return {k: z[k] for k in ("rotations", "translations", "shapes", "instance")}
    n = teacher.num_points
    inputs = np.empty((len(clouds), n, 3), np.float32)
    for i, c in enumerate(clouds):
        c = c / dataset.scale                                                        # [P, 3] model units, object frame
        inputs[i] = c[farthest_point_order(c, n, start=0)]
    R_inst = np.empty((len(clouds), 3, 3)); t_inst = np.empty((len(clouds), 3))
    shapes = None
    for b in tqdm(range(0, len(clouds), batch_size), desc="teacher targets"):
        out = teacher(torch.from_numpy(inputs[b:b + batch_size]))
        S = out["canonical_shape"].numpy().astype(np.float64)                        # [b, M, 3]
        if shapes is None:
            shapes = np.empty((len(clouds),) + S.shape[1:], np.float32)
        hR = out["hypothesis_rotations"].numpy().astype(np.float64)                  # [b, A, 3, 3]
        ht = out["hypothesis_translations"].numpy().astype(np.float64)               # [b, A, 3]
        hs = out["hypothesis_scores"].numpy().astype(np.float64)                     # [b, A]
        for j in range(len(S)):
            r, tt, s = hR[j], ht[j], hs[j]
            if refine > 0:
                r, tt, s = refine_hypotheses(inputs[b + j], S[j], r, tt, s, k=refine, iters=10, bidirectional=True)
            a = int(np.argmin(s))
            R_inst[b + j], t_inst[b + j] = r[a], tt[a]
        shapes[b:b + len(S)] = S
    inst = np.asarray(dataset.instance)                                               # [V]
    Rv = np.asarray(dataset.R, np.float64)                                            # [V, 3, 3]
    res = {"rotations": Rv @ R_inst[inst],                                            # [V, 3, 3]
           "translations": np.einsum("vij,vj->vi", Rv, t_inst[inst]) + dataset.t / dataset.scale,   # [V, 3]
           "shapes": shapes,                                                          # [I, M, 3]
           "instance": inst.astype(np.int64)}                                         # [V]
    if cache_file is not None:
        np.savez(cache_file, key=np.str_(key), **res)
    log(f"teacher targets: {len(clouds)} instances, {len(dataset)} views from {teacher_path} (refine {refine})")
    return res


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


def distillation_loss(out: dict, shapes: torch.Tensor, rotations: torch.Tensor, translations: torch.Tensor,
                      anchors: torch.Tensor, symmetric: bool = False, quat_weight: float = 0.1,
                      select_weight: float = 0.0, select_tolerance: float = 1.5, select_deg: float = 10.0,
                      reach_weight: float = 1.0, reach_deg: float = 40.0, pose_points: int = 64) -> tuple:
    """Student loss against teacher targets; returns (loss, parts dict of floats).

    shape: chamfer(student canonical shape, teacher shape) — pins the student to the teacher's frame.
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
    loss = loss_shape + loss_pose + reach_weight * loss_reach + quat_weight * reg
    parts = {"shape": loss_shape.item(), "pose": loss_pose.item(), "reach": loss_reach.item()}
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
