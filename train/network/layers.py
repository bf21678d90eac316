"""SE(3)-equivariant layers over the 60 icosahedral rotations (EPN-60), in plain PyTorch.

Convention:
    Frame: model units (metres / scale), points centred by the caller (the model subtracts the input centroid).
    Layout: points ``xyz`` [B, P, 3]; group features ``feats`` [B, P, A, C] (A = 60 rotations, channels last, so
    every dense step is a MatMul over the last axis and no transpose is needed before it).
    Rotating the input by the group element g permutes the rotation axis:
    ``feats'[:, :, CAYLEY[g, a]] = feats[:, :, a]``.

Every index operation is ``index_select`` on a flat int64 tensor, which exports to a plain ONNX ``Gather``
(ecosystem notes §1.3); neighbourhoods use ``topk`` (ONNX ``TopK``); downsampling is a prefix slice of the
FPS-ordered input. No Python loop runs over points or rotations.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from equipose.core import icosahedral
from equipose.core.kernel_weights import kernel_aug as core_kernel_aug
from equipose.core.neighbourhoods import input_name, neighbourhood_specs
from equipose.core.presets import LayerSpec

__all__ = ["knn_indices", "flat_rows", "shared_neighbourhoods", "kernel_aug", "hat_weights", "gather_rows",
           "InterSO3Conv", "IntraSO3Conv", "SeparableSO3Block", "instance_norm", "LEAKY_SLOPE", "count_parameters"]

LEAKY_SLOPE = 0.01
A = icosahedral.NUM_ROTATIONS


def knn_indices(support: torch.Tensor, centres: torch.Tensor, k: int, ordered: bool = True) -> torch.Tensor:
    """Indices [B, P2, k] (into ``support``'s points) of the ``k`` nearest support points of each centre.

    support [B, P1, 3]; centres [B, P2, 3] (same frame). ``ordered``: nearest first (a k' < k prefix is then the k'
    nearest); otherwise the set in any order, which a TopK finds about 3× faster (onnxruntime, 256 → 16).
    """
    # rank by ‖s‖² − 2 c·s (‖c‖² is constant per row): one MatMul of augmented vectors [c, 1] · [−2s, ‖s‖²]
    c_aug = torch.cat([centres, torch.ones_like(centres[..., :1])], dim=-1)            # [B, P2, 4]
    s_aug = torch.cat([-2.0 * support, (support * support).sum(-1, keepdim=True)], dim=-1)  # [B, P1, 4]
    rank = c_aug @ s_aug.transpose(1, 2)                                               # [B, P2, P1]
    return torch.topk(rank, k, dim=-1, largest=False, sorted=ordered).indices          # [B, P2, k]


def flat_rows(idx: torch.Tensor, p1: int) -> torch.Tensor:
    """Per-sample indices [B, P2, k] into P1 points → flat int64 [B·P2·k] rows of a [B·P1, ...] view."""
    offset = (torch.arange(idx.shape[0], device=idx.device) * p1).view(-1, 1, 1)
    return (idx + offset).reshape(-1)


def kernel_aug(kernel: np.ndarray, sigma: float) -> torch.Tensor:
    """Kernel points [R, 3] (model units) → [R, 5] rows [2κ/σ, −1/σ, 1 − ‖κ‖²/σ], so that the hat weight
    1 − ‖r − κ‖²/σ of an offset r is one MatMul with [r, ‖r‖², 1] (``hat_weights``; the runtime's
    ``equipose.core.kernel_weights.kernel_aug`` computes format-3 graph inputs with the same rows)."""
    return torch.from_numpy(core_kernel_aug(kernel, sigma))


def hat_weights(xyz: torch.Tensor, spec: LayerSpec, aug: torch.Tensor, knn: torch.Tensor | None = None) -> tuple:
    """Neighbourhoods of a layer's centres and their kernel correlations relu(1 − ‖x_n − x_p − κ‖² / σ).

    xyz [B, P1, 3] (centres: the first ``spec.points_out``); ``aug`` [R, 5] from ``kernel_aug`` for the layer's
    (rotated or unrotated) kernel points; ``knn`` [B, P2, nn] precomputed neighbour indices or None.
    Returns (flat row indices [B·P2·nn] into ``xyz.reshape(B·P1, …)``, weights [B, P2, R, nn]).
    """
    B, P1, _ = xyz.shape
    P2, nn_ = spec.points_out, spec.neighbours
    centres = xyz[:, :P2]                                                              # [B, P2, 3]
    flat = flat_rows(knn if knn is not None else knn_indices(xyz, centres, nn_), P1)  # [B·P2·nn]
    rel = gather_rows(xyz, flat).view(B, P2, nn_, 3) - centres.unsqueeze(2)            # [B, P2, nn, 3]
    rel_aug = torch.cat([rel, (rel * rel).sum(-1, keepdim=True), torch.ones_like(rel[..., :1])], -1)  # [B, P2, nn, 5]
    return flat, F.relu(aug @ rel_aug.transpose(-1, -2))                               # [B, P2, R, nn]


def shared_neighbourhoods(xyz: torch.Tensor, layers, given: dict | None = None) -> list:
    """Neighbour indices [B, P2, nn] for every layer, one kNN per distinct support size
    (``equipose.core.neighbourhoods.neighbourhood_specs``).

    With FPS-ordered input every layer's support is the prefix ``xyz[:, :points_in]`` and its centres the prefix
    ``[:, :points_out]``, so layers sharing a support share one kNN over the most centres and neighbours any of them
    needs. It is sorted (nearest first) only where some layer takes fewer neighbours than that, so that its
    neighbourhood is a prefix of the shared one; a convolution sums over its neighbours, so order is otherwise
    irrelevant. xyz [B, N, 3]. ``given``: ``{input_name(spec): [B, centres, k] int64}`` computed outside (the
    exported graph's inputs), used instead of the TopK.
    """
    knn = {}
    for spec in neighbourhood_specs(layers):
        if given is not None:
            knn[spec.support] = given[input_name(spec)]                            # [B, centres, k]
        else:
            knn[spec.support] = knn_indices(xyz[:, :spec.support], xyz[:, :spec.centres], spec.k,
                                            ordered=spec.ordered)
    return [knn[L.points_in][:, :L.points_out, :L.neighbours] for L in layers]


def gather_rows(x: torch.Tensor, flat_index: torch.Tensor) -> torch.Tensor:
    """``x`` [B, P, ...] → rows ``flat_index`` of ``x.reshape(B·P, ...)`` as [len(flat_index), ...] (ONNX Gather)."""
    return x.reshape((-1,) + tuple(x.shape[2:])).index_select(0, flat_index)


def instance_norm(x: torch.Tensor, eps: float = 1e-5) -> torch.Tensor:
    """Normalise each (sample, channel) over points and rotations. ``x`` [B, P, A, C] → same shape."""
    B, P, A_, C = x.shape
    y = F.instance_norm(x.reshape(B, P * A_, C).transpose(1, 2), eps=eps)  # [B, C, P·A]  (ONNX InstanceNormalization)
    return y.transpose(1, 2).reshape(B, P, A_, C)


class InterSO3Conv(nn.Module):
    """Point convolution with the kernel rotated by all 60 group elements (spec §2).

    out[b, p, a, o] = Σ_{n,k,c} relu(1 − ‖x_n − x_p − A_a·κ_k‖² / σ) · f[b, n, a, c] · W[k, c, o]  (+ bias[o])
    over the ``nn`` nearest neighbours n of the centre p. The centres are the first ``points_out`` input points.
    The hat weights vanish beyond ``kernel_radius + √σ`` (≈1.41·radius), which bounds the neighbourhood.

    Symmetric kernels (13 = centre + icosahedron vertices) take an exact fast path: the group permutes the kernel
    points, A_a·κ_k = κ_{π_a(k)}, so the hat weights are computed once unrotated, aggregated with one GEMM per centre
    (U[k'] = Σ_n w[k', n] · f[n, :, :] over all rotations at once) and routed to (a, k) by a constant Gather.
    """

    def __init__(self, spec: LayerSpec, kernel_points: int):
        super().__init__()
        self.spec, self.k = spec, kernel_points
        kern = icosahedral.kernel_points(kernel_points, spec.kernel_radius)           # [K, 3]
        self.symmetric = kernel_points == 13
        if self.symmetric:
            # π_a(k): centre stays, vertex v goes to VERTEX_PERMUTATION[a, v]
            perm = np.concatenate([np.zeros((A, 1), np.int64), icosahedral.VERTEX_PERMUTATION + 1], 1)  # [A, K]
            assert np.allclose(np.einsum("aij,kj->aki", icosahedral.ANCHORS, kern), kern[perm], atol=1e-9)
            self.register_buffer("route_lift", torch.tensor(perm.reshape(-1), dtype=torch.int64), persistent=False)
            route = perm * A + np.arange(A)[:, None]                                   # [A, K] → row of U [K·A]
            self.register_buffer("route", torch.tensor(route.reshape(-1), dtype=torch.int64), persistent=False)
            rot = kern                                                                 # [K, 3] unrotated
        else:
            rot = np.einsum("aij,kj->aki", icosahedral.ANCHORS, kern).reshape(-1, 3)  # [A·K, 3]
        self.register_buffer("kernel_aug", kernel_aug(rot, spec.sigma), persistent=False)   # [A·K | K, 5]
        self.weight = nn.Parameter(torch.empty(kernel_points * spec.c_in, spec.c_out))  # [K·Cin, Cout], k-major
        self.bias = nn.Parameter(torch.full((spec.c_out,), 1e-3))
        nn.init.xavier_normal_(self.weight.view(kernel_points, spec.c_in, spec.c_out).permute(2, 1, 0),
                               gain=nn.init.calculate_gain("relu"))

    def forward(self, xyz: torch.Tensor, feats: torch.Tensor | None, knn: torch.Tensor | None = None) -> torch.Tensor:
        """xyz [B, P1, 3], feats [B, P1, A, Cin] or None (constant ones: the lifting layer) → [B, P2, A, Cout].
        ``knn`` [B, P2, nn]: precomputed neighbour indices (``shared_neighbourhoods``), else computed here."""
        s, K = self.spec, self.k
        B = xyz.shape[0]
        P2, nn_ = s.points_out, s.neighbours
        flat, w = hat_weights(xyz, s, self.kernel_aug, knn)                            # [B·P2·nn], [B, P2, A·K | K, nn]
        if self.symmetric:
            if feats is None:                                                          # lifting: f ≡ 1
                g = w.sum(-1).index_select(2, self.route_lift).view(B, P2, A, K)       # [B, P2, A, K]
            else:
                C = feats.shape[-1]
                nb = gather_rows(feats, flat).view(B, P2, nn_, A * C)                  # [B, P2, nn, A·C]
                u = torch.matmul(w, nb).view(B, P2, K * A, C)                          # [B, P2, K·A, C]
                g = u.index_select(2, self.route).reshape(B, P2, A, K * C)             # [B, P2, A, K·C]
            return g @ self.weight + self.bias                                         # [B, P2, A, Cout]
        if feats is None:                                                              # lifting: f ≡ 1
            g = w.sum(-1).view(B, P2, A, K)                                            # [B, P2, A, K]
        else:
            C = feats.shape[-1]
            nb = gather_rows(feats, flat).view(B, P2, nn_, A, C)                       # [B, P2, nn, A, C]
            w = w.view(B, P2, A, K, nn_)                                               # [B, P2, A, K, nn]
            g = torch.matmul(w, nb.permute(0, 1, 3, 2, 4))                             # [B, P2, A, K, C]
            g = g.reshape(B, P2, A, K * C)                                             # [B, P2, A, K·C]
        return g @ self.weight + self.bias                                             # [B, P2, A, Cout]


class IntraSO3Conv(nn.Module):
    """Group convolution over the rotation axis (spec §3): out[a] = Σ_k W_k · f[A_a·H_k], no spatial mixing."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.register_buffer("table", torch.tensor(icosahedral.INTRA_NEIGHBOURS.reshape(-1), dtype=torch.int64),
                             persistent=False)
        self.weight = nn.Parameter(torch.empty(icosahedral.INTRA_NEIGHBOURS.shape[1] * c_in, c_out))  # [12·Cin, Cout]
        self.bias = nn.Parameter(torch.full((c_out,), 1e-3))
        nn.init.xavier_normal_(self.weight.view(12, c_in, c_out).permute(2, 1, 0), gain=nn.init.calculate_gain("relu"))

    def forward(self, feats: torch.Tensor) -> torch.Tensor:
        """feats [B, P, A, Cin] → [B, P, A, Cout]."""
        B, P, _, C = feats.shape
        g = feats.index_select(2, self.table)                     # [B, P, A·12, C]   (a-major, k-minor)
        return g.reshape(B, P, A, 12 * C) @ self.weight + self.bias  # [B, P, A, Cout]


class SeparableSO3Block(nn.Module):
    """inter conv → IN → LeakyReLU → intra conv → IN → LeakyReLU, plus a 1×1 skip (IN, LeakyReLU); no act after sum."""

    def __init__(self, spec: LayerSpec, kernel_points: int, lifting: bool = False):
        super().__init__()
        self.spec, self.lifting = spec, lifting
        self.inter, self.intra = self._convolutions(spec, kernel_points)
        self.skip = None if lifting else nn.Linear(spec.c_in, spec.c_out)  # lifting input is constant: no skip

    def _convolutions(self, spec: LayerSpec, kernel_points: int) -> tuple:
        """(inter, intra) convolution modules of the block; subclasses swap in other feature layouts."""
        return InterSO3Conv(spec, kernel_points), IntraSO3Conv(spec.c_out, spec.c_out)

    def forward(self, xyz: torch.Tensor, feats: torch.Tensor | None, knn: torch.Tensor | None = None) -> tuple:
        """xyz [B, P1, 3], feats [B, P1, A, Cin] | None → (xyz [B, P2, 3], feats [B, P2, A, Cout])."""
        P2 = self.spec.points_out
        x = F.leaky_relu(instance_norm(self.inter(xyz, feats, knn)), LEAKY_SLOPE)
        x = F.leaky_relu(instance_norm(self.intra(x)), LEAKY_SLOPE)
        if self.skip is not None:
            x = x + F.leaky_relu(instance_norm(self.skip(feats[:, :P2])), LEAKY_SLOPE)
        return xyz[:, :P2], x


def count_parameters(module: nn.Module) -> int:
    return int(sum(p.numel() for p in module.parameters()))
