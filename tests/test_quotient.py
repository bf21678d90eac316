"""Quotient (12-vertex) layers: against a naive per-point reference, exact equivariance, the vertex tables, the model."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from equipose.core import icosahedral as I  # noqa: E402
from equipose.core.presets import count_params, get_preset, total_macs  # noqa: E402
from equipose.testing import assert_equivariant, torch_layer_fn, torch_model_fn  # noqa: E402
from equipose.train import EquiPoseNet  # noqa: E402
from equipose.train.network.quotient import (QuotientBlock, QuotientInterConv, QuotientIntraConv,  # noqa: E402
                                             lift_pairs)


def _cloud(rng, b, n):
    x = (rng.normal(size=(b, n, 3)) * [0.25, 0.15, 0.1]).astype(np.float32)
    return x - x.mean(1, keepdims=True)


def test_vertex_tables():
    assert I.VERTEX_CLASS.shape == (12, 12) and (np.diag(I.VERTEX_CLASS) == 0).all()
    assert ((I.VERTEX_CLASS == 1).sum(1) == 5).all() and ((I.VERTEX_CLASS == 3).sum(1) == 1).all()
    for g in range(60):                                                # rotations preserve the classes
        p = I.VERTEX_PERMUTATION[g]
        assert (I.VERTEX_CLASS[np.ix_(p, p)] == I.VERTEX_CLASS).all()
    pairs = {tuple(p) for p in I.ROTATION_VERTEX_PAIR}
    assert len(pairs) == 60 and all(I.VERTEX_CLASS[a, b] == 1 for a, b in pairs)


def _naive_inter(conv, xyz, feats):
    """Loop reference of QuotientInterConv: Σ_n Σ_k hat(x_n − x_p, κ_k) f[n, v] W[class(v, k)]."""
    s = conv.spec
    kern = I.kernel_points(13, s.kernel_radius)                                     # [13, 3]
    W = conv.weight.detach().numpy().reshape(5, -1, s.c_out)                        # [5, Cin, Cout]
    x = xyz[0].numpy().astype(np.float64)
    out = np.zeros((s.points_out, 12, s.c_out))
    for p in range(s.points_out):
        d = ((x - x[p]) ** 2).sum(1)
        for n in np.argsort(d, kind="stable")[: s.neighbours]:
            hat = np.maximum(0.0, 1.0 - (((x[n] - x[p]) - kern) ** 2).sum(1) / s.sigma)  # [13]
            for v in range(12):
                f = np.ones(1) if feats is None else feats[0, n, v].numpy()
                for k in range(13):
                    c = 0 if k == 0 else 1 + I.VERTEX_CLASS[v, k - 1]
                    out[p, v] += hat[k] * f @ W[c]
    return out + conv.bias.detach().numpy()


def test_inter_conv_matches_loop_reference(rng):
    torch.manual_seed(0)
    cfg = get_preset("edge-q")
    xyz = torch.from_numpy(_cloud(rng, 1, cfg.num_points))
    lift = QuotientInterConv(cfg.layers[0])
    with torch.no_grad():
        f0 = lift(xyz, None)                                                         # [1, 128, 12, 16]
    assert np.allclose(f0[0].numpy(), _naive_inter(lift, xyz, None), atol=1e-4)
    conv = QuotientInterConv(cfg.layers[1])
    x1 = xyz[:, : cfg.layers[0].points_out]
    f0 = f0 / f0.abs().max()
    with torch.no_grad():
        f1 = conv(x1, f0)
    assert np.allclose(f1[0].numpy(), _naive_inter(conv, x1, f0), atol=1e-4)


def test_intra_conv_matches_loop_reference(rng):
    torch.manual_seed(1)
    conv = QuotientIntraConv(6, 5)
    f = torch.from_numpy(rng.normal(size=(2, 3, 12, 6)).astype(np.float32))
    with torch.no_grad():
        out = conv(f).numpy()
    W = conv.weight.detach().numpy().reshape(6, 4, 5)                               # [Cin, class, Cout]
    ref = np.zeros_like(out)
    for v in range(12):
        for u in range(12):
            ref[:, :, v] += f.numpy()[:, :, u] @ W[:, I.VERTEX_CLASS[v, u]]
    assert np.allclose(out, ref + conv.bias.detach().numpy(), atol=1e-5)


def test_blocks_and_lift_equivariant(rng):
    torch.manual_seed(2)
    cfg = get_preset("edge-q")
    b0, b1 = QuotientBlock(cfg.layers[0], lifting=True).eval(), QuotientBlock(cfg.layers[1]).eval()

    def stack(p):
        xyz, f = b1(*b0(p, None))
        return f                                                                      # [B, P, 12, C]

    x = _cloud(rng, 1, cfg.num_points)
    errs = assert_equivariant(torch_layer_fn(stack), x, rotations=range(0, 60, 4), translation=np.zeros(3))
    assert errs["features"] < 1e-4
    # the pair lift turns vertex descriptors into rotation features (re-indexed by CAYLEY): checked as features
    lifted = torch_layer_fn(lambda p: lift_pairs(stack(p).amax(1)).unsqueeze(1))
    errs = assert_equivariant(lifted, x, rotations=range(1, 60, 6), translation=np.zeros(3))
    assert errs["features"] < 1e-4


@pytest.mark.parametrize("partial", [True, False])
def test_quotient_model_equivariant(rng, partial):
    torch.manual_seed(3)
    model = EquiPoseNet("edge-q", partial=partial)
    errs = assert_equivariant(torch_model_fn(model), _cloud(rng, 2, model.num_points) + 0.2, rotations=range(0, 60, 5),
                              atol=2e-4)
    assert errs["features"] < 2e-4
    assert sum(p.numel() for p in model.parameters()) == count_params("edge-q")
    assert total_macs("edge-q") < total_macs("edge-a") / 4                             # the point of the quotient


def test_quotient_needs_symmetric_kernel():
    with pytest.raises(ValueError, match="13-point"):
        get_preset("edge-q").replace(name="bad", kernel_points=24)
