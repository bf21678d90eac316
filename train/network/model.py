"""The equi-pose network: EPN-60 backbone, invariant shape branch, equivariant 60-hypothesis pose branch, scores.

Convention:
    Input ``points`` [B, N, 3] float32 in model units (metres / scale), camera frame, FPS-ordered (every in-graph
    downsampling is a prefix slice). Rotations act on column vectors: a posed canonical point is ``R @ z + t``;
    with row arrays that is ``z @ R.T + t``. Quaternions (w, x, y, z).
    Outputs (the ONNX contract, DESIGN.md):
        canonical_shape         [B, M, 3]      in (−0.5, 0.5)³, invariant to rotations of the input
        hypothesis_rotations    [B, 60, 3, 3]  R_j = A_j · R(Δq_j)
        hypothesis_translations [B, 60, 3]     t_j = A_j · Δt_j + t0 (t0 = input centroid; Δt ≡ 0 for complete shapes)
        hypothesis_scores       [B, 60]        chamfer of R_j·Z + t_j to the input (lower is better)
    Equivariance: input g·X (g in the group, about the origin) → same Z, hypotheses (g·R_j, g·t_j) re-indexed by
    j ↦ CAYLEY[g, j], scores re-indexed likewise.
"""
from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from equipose.core import icosahedral
from equipose.core.presets import ModelConfig, get_preset

from equipose.train.network.layers import LEAKY_SLOPE, SeparableSO3Block, shared_neighbourhoods
from equipose.train.network.quotient import QuotientBlock, lift_pairs

__all__ = ["EquiPoseNet", "quaternion_to_matrix", "squared_distances", "hypothesis_scores", "OUTPUT_NAMES",
           "chamfer_min_of_60_loss", "axial_symmetry_loss"]

A = icosahedral.NUM_ROTATIONS
OUTPUT_NAMES = ("canonical_shape", "hypothesis_rotations", "hypothesis_translations", "hypothesis_scores")


def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Unit-normalised (w, x, y, z) quaternions [..., 4] → rotation matrices [..., 3, 3] (Hamilton)."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-8)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], -1).reshape(q.shape[:-1] + (3, 3))


def squared_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Pairwise squared distances as MatMuls. a [..., N, 3], b [..., M, 3] → [..., N, M] (clamped ≥ 0)."""
    d2 = (a * a).sum(-1, keepdim=True) - 2.0 * a @ b.transpose(-1, -2) + (b * b).sum(-1).unsqueeze(-2)
    return d2.clamp_min(0.0)


def hypothesis_scores(points: torch.Tensor, shape: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
                      bidirectional: bool, score_points: int = 0) -> torch.Tensor:
    """Chamfer (squared distances) between each posed reconstruction R_j·Z + t_j and the input.

    points [B, N, 3]; shape Z [B, M, 3]; R [B, J, 3, 3]; t [B, J, 3] → [B, J].
    Computed in the hypothesis frame, R_jᵀ(x − t_j) vs Z (distances are rigid-invariant), so Z is posed 0 times.
    ``bidirectional=False``: mean over input points of the nearest reconstruction point (partial input);
    ``True`` adds the mean over reconstruction points of the nearest input point (complete input).
    ``score_points`` > 0 scores with the first ``score_points`` input points only (FPS-ordered input: a uniform subset).
    """
    x = points[:, :score_points] if 0 < score_points < points.shape[1] else points     # [B, N', 3]
    Rt = R.transpose(-1, -2)                                           # [B, J, 3, 3]
    # columns of R_jᵀ(x − t_j), channel-first so the broadcast subtraction runs along the contiguous point axis
    local = Rt @ x.transpose(1, 2).unsqueeze(1) - Rt @ t.unsqueeze(-1)  # [B, J, 3, N']
    # all squared distances in one MatMul: [x, ‖x‖², 1] · [−2z, 1, ‖z‖²]; clamp after the min (same result)
    a = torch.cat([local, (local * local).sum(2, keepdim=True), torch.ones_like(local[:, :, :1])], 2)  # [B, J, 5, N']
    b = torch.cat([-2.0 * shape, torch.ones_like(shape[..., :1]), (shape * shape).sum(-1, keepdim=True)], -1)
    # b: [B, M, 5]
    d2 = a.transpose(2, 3) @ b.transpose(1, 2).unsqueeze(1)            # [B, J, N', M]
    score = d2.min(dim=3).values.clamp_min(0.0).mean(dim=2)            # [B, J]
    if bidirectional:
        score = score + d2.min(dim=2).values.clamp_min(0.0).mean(dim=2)
    return score


def _mlp_bn(c_in: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(c_in, c_out), nn.BatchNorm1d(c_out), nn.ReLU())


def _apply_rowwise(seq: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """Apply a [N, C] module to the last axis of any-rank ``x``."""
    return seq(x.reshape(-1, x.shape[-1])).reshape(x.shape[:-1] + (-1,))


class PoseHead(nn.Module):
    """Equivariant pose branch: per-rotation residual quaternion and translation.

    [B, P, A, C] → q [B, A, 4], t [B, A, 3]."""

    def __init__(self, c: int, h: int):
        super().__init__()
        self.mlp = nn.Sequential(_mlp_bn(c, h), _mlp_bn(h, h))
        self.out = nn.Linear(h, 7)

    def forward(self, feats):
        x = _apply_rowwise(self.mlp, feats).amax(dim=1)                    # [B, A, H]  max over points
        y = self.out(x)                                                    # [B, A, 7]
        return y[..., :4], y[..., 4:]


class InvariantHead(nn.Module):
    """Invariant shape branch: features + xyz in each rotation's frame → max over points → max over rotations → z."""

    def __init__(self, c: int, h: int, latent: int):
        super().__init__()
        self.mlp = nn.Sequential(_mlp_bn(c, h), _mlp_bn(h, h))
        self.point = nn.Linear(h + 3, latent)
        self.norm = nn.BatchNorm1d(latent)
        anchors = icosahedral.ANCHORS                                      # row-form: x @ A_a = (A_aᵀ x)ᵀ
        anchors_cat = torch.tensor(anchors.transpose(1, 0, 2).reshape(3, A * 3), dtype=torch.float32)
        self.register_buffer("anchors_cat", anchors_cat,
                             persistent=False)

    def forward(self, xyz, feats):
        """xyz [B, P, 3] (surviving points), feats [B, P, A, C] → z [B, latent]."""
        B, P = xyz.shape[:2]
        h = _apply_rowwise(self.mlp, feats)                                # [B, P, A, H]
        local = xyz - xyz.mean(dim=1, keepdim=True)                        # [B, P, 3]
        xr = (local @ self.anchors_cat).view(B, P, A, 3)                   # [B, P, A, 3]  A_aᵀ x_p
        x = self.point(torch.cat([h, xr], dim=-1)).amax(dim=1)             # [B, A, L]
        x = F.relu(_apply_rowwise(self.norm, x))                           # [B, A, L]
        return x.amax(dim=1)                                               # [B, L]


class QuotientPoseHead(nn.Module):
    """Pose branch on vertex descriptors: MLP → max over points → lift vertex pairs to the 60 rotations → MLP.

    feats [B, P, 12, C] → q [B, A, 4], t [B, A, 3] (the same contract as ``PoseHead``).
    """

    def __init__(self, c: int, h: int):
        super().__init__()
        self.mlp = nn.Sequential(_mlp_bn(c, h), _mlp_bn(h, h))
        self.pair = nn.Linear(2 * h, h)
        self.out = nn.Linear(h, 7)

    def forward(self, feats):
        x = _apply_rowwise(self.mlp, feats).amax(dim=1)                    # [B, 12, H]  max over points
        x = F.leaky_relu(self.pair(lift_pairs(x)), LEAKY_SLOPE)            # [B, A, H]
        y = self.out(x)                                                    # [B, A, 7]
        return y[..., :4], y[..., 4:]


class QuotientInvariantHead(nn.Module):
    """Invariant shape branch on vertex descriptors: features + (projection on v, squared distance from the v axis)
    → max over points → max over vertices → z. xyz [B, P, 3], feats [B, P, 12, C] → [B, latent]."""

    def __init__(self, c: int, h: int, latent: int):
        super().__init__()
        self.mlp = nn.Sequential(_mlp_bn(c, h), _mlp_bn(h, h))
        self.point = nn.Linear(h + 2, latent)
        self.norm = nn.BatchNorm1d(latent)
        self.register_buffer("vertices_t", torch.tensor(icosahedral.VERTICES.T, dtype=torch.float32), persistent=False)

    def forward(self, xyz, feats):
        h = _apply_rowwise(self.mlp, feats)                                # [B, P, 12, H]
        local = xyz - xyz.mean(dim=1, keepdim=True)                        # [B, P, 3]
        proj = local @ self.vertices_t                                     # [B, P, 12]  x·v
        perp = ((local * local).sum(-1, keepdim=True) - proj * proj).clamp_min(0.0)  # [B, P, 12]  ‖x‖² − (x·v)²
        x = self.point(torch.cat([h, proj.unsqueeze(-1), perp.unsqueeze(-1)], dim=-1)).amax(dim=1)  # [B, 12, L]
        x = F.relu(_apply_rowwise(self.norm, x))                           # [B, 12, L]
        return x.amax(dim=1)                                               # [B, L]


class ShapeDecoder(nn.Module):
    """z [B, L] → canonical shape [B, M, 3] in (−0.5, 0.5)³ (sigmoid − 0.5)."""

    def __init__(self, latent: int, hidden: tuple, m: int):
        super().__init__()
        dims = (latent,) + tuple(hidden)
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.out = nn.Linear(dims[-1], 3 * m)
        self.m = m

    def forward(self, z):
        for lin in self.hidden:
            z = F.leaky_relu(lin(z), LEAKY_SLOPE)
        return torch.sigmoid(self.out(z)).view(-1, self.m, 3) - 0.5


class EquiPoseNet(nn.Module):
    """The full model. ``partial`` selects the partial-input variant (constrained qw, translation residual,
    one-directional scores); otherwise complete-shape (free quaternion, t = centroid, bidirectional scores)."""

    def __init__(self, config: ModelConfig | str = "paper", partial: bool = True):
        super().__init__()
        cfg = get_preset(config)
        self.config, self.partial = cfg, bool(partial)
        c = cfg.channels[-1]
        if cfg.quotient:                                              # 12-vertex descriptors (network/quotient.py)
            self.blocks = nn.ModuleList(QuotientBlock(L, lifting=(i == 0)) for i, L in enumerate(cfg.layers))
            self.pose_head = QuotientPoseHead(c, cfg.head_channels)
            self.inv_head = QuotientInvariantHead(c, cfg.head_channels, cfg.latent)
        else:
            self.blocks = nn.ModuleList(SeparableSO3Block(L, cfg.kernel_points, lifting=(i == 0))
                                        for i, L in enumerate(cfg.layers))
            self.pose_head = PoseHead(c, cfg.head_channels)
            self.inv_head = InvariantHead(c, cfg.head_channels, cfg.latent)
        self.decoder = ShapeDecoder(cfg.latent, cfg.decoder_hidden, cfg.num_canonical_points)
        self.register_buffer("anchors", torch.tensor(icosahedral.ANCHORS, dtype=torch.float32),   # [A, 3, 3]
                             persistent=False)
        self.cos_theta_max = math.cos(math.radians(cfg.theta_max_deg))

    @property
    def num_points(self) -> int:
        return self.config.num_points

    def backbone(self, centred: torch.Tensor, neighbours: dict | None = None) -> tuple:
        """centred [B, N, 3] → (xyz [B, P, 3], feats [B, P, A, C]; [B, P, 12, C] for a quotient backbone).
        ``neighbours``: the kNN index sets computed outside (``equipose.core.neighbourhoods``), or None (TopK)."""
        xyz, feats = centred, None
        knn = shared_neighbourhoods(centred, self.config.layers, neighbours)    # one kNN per support size
        for blk, nb in zip(self.blocks, knn):
            xyz, feats = blk(xyz, feats, nb)
        return xyz, feats

    def residual_quaternion(self, q_raw: torch.Tensor) -> torch.Tensor:
        """Raw [B, A, 4] → residual quaternion (unnormalised). Partial: qw ∈ (cos θmax, 1) by a sigmoid."""
        if not self.partial:
            return q_raw
        qw = self.cos_theta_max + (1.0 - self.cos_theta_max) * torch.sigmoid(q_raw[..., :1])
        return torch.cat([qw, q_raw[..., 1:]], dim=-1)

    def forward(self, points: torch.Tensor, return_aux: bool = False, neighbours: dict | None = None):
        """points [B, N, 3] → dict of the four contract outputs (+ ``quaternion_norm`` [B, A] if ``return_aux``).
        ``neighbours``: ``{name: [B, centres, k] int64}`` per ``equipose.core.neighbourhoods`` (the exported graph's
        inputs; distances do not change under the centring, so they may come from ``points``), or None."""
        if points.dim() != 3 or points.shape[-1] != 3:
            raise ValueError(f"points must be [B, N, 3], got {tuple(points.shape)}")
        t0 = points.mean(dim=1, keepdim=True)                                   # [B, 1, 3]
        xyz, feats = self.backbone(points - t0, neighbours)                     # [B, P, 3], [B, P, A, C]
        q_raw, t_raw = self.pose_head(feats)                                    # [B, A, 4], [B, A, 3]
        dq = self.residual_quaternion(q_raw)                                    # [B, A, 4]
        R = self.anchors @ quaternion_to_matrix(dq)                             # [B, A, 3, 3]
        if self.partial:
            t = (self.anchors @ t_raw.unsqueeze(-1)).squeeze(-1) + t0           # [B, A, 3]
        else:
            t = t0.expand(-1, A, -1) + 0.0 * t_raw                              # [B, A, 3]
        z = self.inv_head(xyz, feats)                                           # [B, L]
        shape = self.decoder(z)                                                 # [B, M, 3]
        scores = hypothesis_scores(points, shape, R, t, bidirectional=not self.partial,
                                   score_points=self.config.score_points)                 # [B, A]
        out = {"canonical_shape": shape, "hypothesis_rotations": R, "hypothesis_translations": t,
               "hypothesis_scores": scores}
        if return_aux:
            out["quaternion_norm"] = dq.norm(dim=-1)
            out["features"] = feats
        return out
