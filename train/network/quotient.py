"""Quotient layers: equivariant features on the 12 icosahedron vertices instead of the 60 rotations (E2PN-style).

Convention:
    Frame: model units (metres / scale), points centred by the caller.
    Layout: points ``xyz`` [B, P, 3]; vertex features ``feats`` [B, P, V, C] (V = 12 vertices, channels last).
    Rotating the input by group element g permutes the vertex axis: ``feats'[:, :, VERTEX_PERMUTATION[g, v]] =
    feats[:, :, v]``. A vertex feature is a descriptor *along* the 5-fold axis v: its kernels are symmetric under the
    five rotations about v, so it carries 12 instead of 60 copies per channel (5× less memory traffic, ~13× fewer
    MACs in the kernel GEMM). ``lift_pairs`` turns vertex descriptors back into 60 rotation features: rotation g is the
    unique one carrying the adjacent vertex pair (0, n0) to ``ROTATION_VERTEX_PAIR[g]``.

Kernels (13 points: centre + the 12 vertices, as in the symmetric fast path of ``layers.InterSO3Conv``): the weight of
kernel point k for the descriptor along v depends only on the class of k seen from v (centre, same vertex, near ring,
far ring, antipode: 5 classes), which every group element preserves. The intra (group) convolution mixes the 12
descriptors of a point with one weight per vertex class (same, near ring, far ring, antipode: 4 classes).
Every index operation is a constant ``index_select`` (ONNX Gather); there is no Python loop over points or vertices.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

from equipose.core import icosahedral
from equipose.core.kernel_weights import CLASS_MATRIX
from equipose.core.presets import LayerSpec

from equipose.train.network.layers import SeparableSO3Block, hat_weights, kernel_aug

__all__ = ["QuotientInterConv", "QuotientIntraConv", "QuotientBlock", "lift_pairs", "V", "KERNEL_CLASSES",
           "VERTEX_CLASSES"]

V = 12
KERNEL_CLASSES = 5          # centre, same vertex, near ring, far ring, antipode
VERTEX_CLASSES = 4          # same, near ring, far ring, antipode


def _vertex_class_matrix() -> np.ndarray:
    """[V, V·VERTEX_CLASSES] 0/1: row v sums the class-c transform of vertex u (column u·4 + c) iff class(v, u) = c."""
    m = np.zeros((V, V * VERTEX_CLASSES), np.float32)
    for v in range(V):
        for u in range(V):
            m[v, u * VERTEX_CLASSES + int(icosahedral.VERTEX_CLASS[v, u])] = 1.0
    return m


class QuotientInterConv(nn.Module):
    """Point convolution producing vertex descriptors (13 symmetric kernel points, weights shared per class).

    out[b, p, v, o] = Σ_n Σ_k relu(1 − ‖x_n − x_p − κ_k‖² / σ) · f[b, n, v, c] · W[class(v, k), c, o]  (+ bias[o])
    over the ``nn`` nearest neighbours n of the centre p (the first ``points_out`` input points).
    """

    def __init__(self, spec: LayerSpec):
        super().__init__()
        self.spec = spec
        kern = icosahedral.kernel_points(13, spec.kernel_radius)                       # [13, 3]
        self.register_buffer("kernel_aug", kernel_aug(kern, spec.sigma), persistent=False)  # [13, 5]
        self.register_buffer("class_sum", torch.tensor(CLASS_MATRIX), persistent=False)   # [V·5, 13]
        self.weight = nn.Parameter(torch.empty(KERNEL_CLASSES * spec.c_in, spec.c_out))  # [5·Cin, Cout], class-major
        self.bias = nn.Parameter(torch.full((spec.c_out,), 1e-3))
        nn.init.xavier_normal_(self.weight.view(KERNEL_CLASSES, spec.c_in, spec.c_out).permute(2, 1, 0),
                               gain=nn.init.calculate_gain("relu"))

    def forward(self, xyz: torch.Tensor, feats: torch.Tensor | None, knn: torch.Tensor | None = None) -> torch.Tensor:
        """xyz [B, P1, 3], feats [B, P1, V, Cin] or None (constant ones: the lifting layer) → [B, P2, V, Cout].
        ``knn`` [B, P2, nn]: precomputed neighbour indices (``layers.shared_neighbourhoods``), else computed here."""
        s = self.spec
        B = xyz.shape[0]
        P2, nn_ = s.points_out, s.neighbours
        flat, w = hat_weights(xyz, s, self.kernel_aug, knn)                            # [B·P2·nn], [B, P2, 13, nn]
        wc = self.class_sum @ w                                                        # [B, P2, V·5, nn] per class
        if feats is None:                                                              # lifting: f ≡ 1
            g = wc.sum(-1).view(B, P2, V, KERNEL_CLASSES)                              # [B, P2, V, 5]
            return g @ self.weight + self.bias                                         # [B, P2, V, Cout]
        # vertex-major, so that the gathered neighbourhoods need no transpose: only the small per-point
        # tensors (features in, result out) change layout
        C = feats.shape[-1]
        fv = feats.permute(2, 0, 1, 3).reshape(V, -1, C)                               # [V, B·P1, C]
        nb = fv.index_select(1, flat).view(V, -1, nn_, C)                              # [V, B·P2, nn, C]
        wv = wc.view(-1, V, KERNEL_CLASSES * nn_).transpose(0, 1)                      # [V, B·P2, 5·nn]
        g = wv.reshape(V, -1, KERNEL_CLASSES, nn_) @ nb                                # [V, B·P2, 5, C]
        y = g.reshape(V, -1, KERNEL_CLASSES * C) @ self.weight + self.bias             # [V, B·P2, Cout]
        return y.view(V, B, P2, -1).permute(1, 2, 0, 3)                                # [B, P2, V, Cout]


class QuotientIntraConv(nn.Module):
    """Group convolution on vertex descriptors: out[v] = Σ_u W[class(v, u)] · f[u] (one MatMul + one constant
    MatMul)."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.c_out = c_out
        self.register_buffer("classes", torch.tensor(_vertex_class_matrix()), persistent=False)   # [V, V·4]
        self.weight = nn.Parameter(torch.empty(c_in, VERTEX_CLASSES * c_out))          # [Cin, 4·Cout], class-major
        self.bias = nn.Parameter(torch.full((c_out,), 1e-3))
        nn.init.xavier_normal_(self.weight.view(c_in, VERTEX_CLASSES, c_out).permute(2, 0, 1),
                               gain=nn.init.calculate_gain("relu"))

    def forward(self, feats: torch.Tensor) -> torch.Tensor:
        """feats [B, P, V, Cin] → [B, P, V, Cout]."""
        B, P = feats.shape[:2]
        y = (feats @ self.weight).view(B, P, V * VERTEX_CLASSES, self.c_out)           # [B, P, V·4, Cout] (u, class)
        return self.classes @ y + self.bias                                            # [B, P, V, Cout]


class QuotientBlock(SeparableSO3Block):
    """inter conv → IN → LeakyReLU → intra conv → IN → LeakyReLU, plus a 1×1 skip (IN, LeakyReLU), on vertex features.

    The same block as ``layers.SeparableSO3Block`` (its ``forward``) with the quotient convolutions:
    xyz [B, P1, 3], feats [B, P1, V, Cin] | None → (xyz [B, P2, 3], feats [B, P2, V, Cout]).
    """

    def __init__(self, spec: LayerSpec, lifting: bool = False):
        super().__init__(spec, 13, lifting)

    def _convolutions(self, spec: LayerSpec, kernel_points: int) -> tuple:
        return QuotientInterConv(spec), QuotientIntraConv(spec.c_out, spec.c_out)


_PAIR = torch.tensor(icosahedral.ROTATION_VERTEX_PAIR.reshape(-1), dtype=torch.int64)


def lift_pairs(x: torch.Tensor) -> torch.Tensor:
    """Vertex descriptors [B, V, C] → rotation features [B, 60, 2C]: rotation g reads its vertex pair (equivariant)."""
    B, _, C = x.shape
    return x.index_select(1, _PAIR.to(x.device)).reshape(B, icosahedral.NUM_ROTATIONS, 2 * C)
