"""Named model presets (one registry, like timm configs) and an analytic cost model (parameters, MACs).

Convention:
    Lengths (radii, kernel radii) are in *model units*: metres divided by the model's ``scale``. For ModelNet-style
    data the unit is the bounding-box diagonal (spec §7), so an object spans about 0.5–0.7 units.
    Every layer is one ``SeparableSO3ConvBlock`` (inter point conv + intra group conv + skip); blocks come in pairs,
    the first of each pair strided (point count halved by a prefix slice of the FPS-ordered input).

This module is torch-free: train, export and the SDK all read the same registry.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

__all__ = ["LayerSpec", "ModelConfig", "PRESETS", "get_preset", "list_presets", "register_preset", "layer_costs",
           "total_macs", "count_params"]


@dataclass(frozen=True)
class LayerSpec:
    """One separable layer. ``points_in → points_out`` (prefix slice when they differ)."""
    c_in: int
    c_out: int
    points_in: int
    points_out: int
    radius: float          # neighbourhood radius (model units)
    sigma: float           # kernel correlation width (squared model units): w = relu(1 - d² / sigma)
    kernel_radius: float   # radius of the kernel point set (model units)
    neighbours: int        # kNN size (neighbours beyond ``radius`` are masked out)


@dataclass(frozen=True)
class ModelConfig:
    """A full model configuration. ``layers`` is derived from the compact fields in ``__post_init__``."""
    name: str
    num_points: int = 1024                      # N, input points (FPS-ordered)
    channels: tuple = (32, 32, 64, 64, 128, 128, 256, 256)
    strides: tuple = (2, 1, 2, 1, 2, 1, 2, 1)
    radii: tuple = (0.08, 0.1131, 0.16, 0.16, 0.2263, 0.2263, 0.32, 0.32)
    neighbours: tuple = (64, 32, 64, 32, 64, 32, 64, 32)
    kernel_points: int = 24                     # 24 (kpsphere24) or 13 (centre + icosahedron vertices)
    kernel_ratio: float = 0.7                   # kernel radius = 0.7 · radius
    sigma_ratio: float = 0.5                    # sigma = 0.5 · radius²
    head_channels: int = 128
    latent: int = 128
    decoder_hidden: tuple = (256, 256)
    num_canonical_points: int = 1024            # M, points of the canonical shape
    theta_max_deg: float = 36.0                 # partial mode: residual quaternion qw >= cos(theta_max)
    quotient: bool = False                      # backbone on the 12 vertex descriptors (E2PN-style), lifted at the heads
    score_points: int = 0                       # hypothesis scores from the first K (FPS) input points; 0 = all N
    description: str = ""
    layers: tuple = field(default=(), compare=False)

    def __post_init__(self):
        n = len(self.channels)
        if not (len(self.strides) == len(self.radii) == len(self.neighbours) == n):
            raise ValueError(f"preset {self.name!r}: channels/strides/radii/neighbours must have equal length")
        if self.quotient and self.kernel_points != 13:
            raise ValueError(f"preset {self.name!r}: quotient (vertex) features need the 13-point symmetric kernel")
        layers, c_in, p = [], 1, self.num_points
        for c, s, r, k in zip(self.channels, self.strides, self.radii, self.neighbours):
            p_out = math.ceil(p / s)
            layers.append(LayerSpec(c_in, c, p, p_out, r, self.sigma_ratio * r * r, self.kernel_ratio * r, min(k, p)))
            c_in, p = c, p_out
        object.__setattr__(self, "layers", tuple(layers))

    @property
    def feature_points(self) -> int:
        """Points left after the last layer."""
        return self.layers[-1].points_out

    def replace(self, **changes) -> "ModelConfig":
        """A copy with fields changed (``layers`` is re-derived)."""
        changes.setdefault("layers", ())
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d.pop("layers")
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "ModelConfig":
        d = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items() if k != "layers"}
        return cls(**d)


PRESETS: dict = {}


def register_preset(cfg: ModelConfig) -> ModelConfig:
    """Add a preset to the registry (name must be new)."""
    if cfg.name in PRESETS:
        raise ValueError(f"preset {cfg.name!r} already registered")
    PRESETS[cfg.name] = cfg
    return cfg


register_preset(ModelConfig(
    name="paper",
    description="Reference EPN-60 of equi-pose (spec §4.3): 1024 points, 8 separable layers 32→256, 24 kernel points.",
))

register_preset(ModelConfig(
    name="small",
    num_points=512,
    channels=(16, 16, 32, 32, 64, 64, 128, 128),
    radii=(0.1131, 0.16, 0.16, 0.2263, 0.2263, 0.32, 0.32, 0.40),
    neighbours=(24, 16, 24, 16, 24, 16, 16, 16),
    head_channels=64,
    latent=64,
    decoder_hidden=(128, 128),
    num_canonical_points=512,
    description="CPU training preset: 512 points, half the channels, fewer neighbours.",
))

register_preset(ModelConfig(
    name="tiny",
    num_points=256,
    channels=(8, 8, 16, 16),
    strides=(2, 1, 2, 1),
    radii=(0.16, 0.2263, 0.2263, 0.32),
    neighbours=(12, 8, 12, 8),
    kernel_points=13,
    head_channels=32,
    latent=32,
    decoder_hidden=(64, 64),
    num_canonical_points=256,
    description="Test-suite preset: 256 points, 4 layers, 13 kernel points. Not for accuracy.",
))


# CPU edge candidates: symmetric 13-point kernels (exact fast path), 256 input points, narrow widths.
register_preset(ModelConfig(
    name="edge-a",
    num_points=256,
    channels=(16, 16, 32, 32),
    strides=(2, 1, 2, 1),
    radii=(0.16, 0.2263, 0.2263, 0.32),
    neighbours=(16, 12, 16, 12),
    kernel_points=13,
    head_channels=64,
    latent=64,
    decoder_hidden=(128, 128),
    num_canonical_points=256,
    description="Edge candidate A: 256 points, 4 layers 16→32, 13 symmetric kernel points.",
))

register_preset(ModelConfig(
    name="edge-b",
    num_points=256,
    channels=(16, 16, 32, 32, 64, 64),
    strides=(2, 1, 2, 1, 2, 1),
    radii=(0.1131, 0.16, 0.16, 0.2263, 0.2263, 0.32),
    neighbours=(16, 12, 16, 12, 16, 12),
    kernel_points=13,
    head_channels=64,
    latent=64,
    decoder_hidden=(128, 128),
    num_canonical_points=256,
    description="Edge candidate B: 256 points, 6 layers 16→64, 13 symmetric kernel points.",
))


# Quotient candidates: the backbone on 12 vertex descriptors instead of 60 rotation copies.
register_preset(PRESETS["edge-a"].replace(
    name="edge-q",
    quotient=True,
    score_points=128,
    description="Edge candidate Q: edge-a's layout on 12 vertex descriptors (E2PN-style quotient), lifted at the heads; "
                "hypotheses scored on the first 128 input points.",
))

register_preset(PRESETS["edge-q"].replace(
    name="edge-qw",
    channels=(32, 32, 64, 64),
    description="Edge candidate QW: edge-q with doubled channel widths (32→64).",
))


# The chosen edge preset (docs/benchmarks.md): edge-q's configuration — the fastest candidate and, at equal
# training budget and after distillation, the most accurate (airplane partial 3.51° median vs edge-a's 6.00°).
# Shipped weights bind to presets in equipose.models.WEIGHTS (arch.tag); a file whose metadata says "edge-q" has the
# same configuration.
register_preset(PRESETS["edge-q"].replace(
    name="edge",
    description="CPU edge preset (= edge-q): 256 points, 4 quotient layers 16→32 on 12 vertex descriptors, 13 "
                "symmetric kernel points, scores on 128 points; see docs/benchmarks.md.",
))


def list_presets() -> list:
    return sorted(PRESETS)


def get_preset(name) -> ModelConfig:
    """Look up a preset by name (a ``ModelConfig`` passes through); an ``arch.tag`` model name gives its ``arch``."""
    if isinstance(name, ModelConfig):
        return name
    if isinstance(name, str) and name not in PRESETS and "." in name:
        name = name.partition(".")[0]                                           # "edge.cup-tabletop" → "edge"
    try:
        return PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown preset {name!r}; choose one of {', '.join(list_presets())}") from None


# ----------------------------------------------------------------------------------------------------------------------
# Analytic cost model (per object, batch 1). A = 60 rotations, K = kernel points, 12 = intra neighbours.
A_ROT, INTRA_K = 60, 12


def layer_costs(cfg: ModelConfig, partial: bool = True) -> list:
    """Rows ``{"name", "params", "macs"}`` for every layer and head (multiply-accumulates of matmul-like work)."""
    cfg = get_preset(cfg)
    if cfg.quotient:
        return _quotient_layer_costs(cfg, partial)
    K, rows = cfg.kernel_points, []
    for i, L in enumerate(cfg.layers):
        P2, nn = L.points_out, L.neighbours
        inter_p = L.c_in * K * L.c_out + L.c_out
        intra_p = L.c_out * INTRA_K * L.c_out + L.c_out
        skip_p = (L.c_in * L.c_out + L.c_out) if i > 0 else 0  # layer 0 lifts constant features: no skip
        rot_k = K if K == 13 else A_ROT * K       # symmetric 13-point kernel: weights computed once, unrotated
        macs = (P2 * nn * rot_k * 5                # hat weights (one augmented matmul)
                + P2 * A_ROT * K * nn * L.c_in      # neighbour aggregation
                + P2 * A_ROT * K * L.c_in * L.c_out  # inter dense matmul
                + P2 * A_ROT * INTRA_K * L.c_out * L.c_out  # intra dense matmul
                + (P2 * A_ROT * L.c_in * L.c_out if i > 0 else 0))  # skip
        rows.append({"name": f"block{i // 2}.layer{i % 2} ({L.c_in}→{L.c_out}, {L.points_in}→{P2} pts, nn {nn})",
                     "params": inter_p + intra_p + skip_p, "macs": macs})
    C, H, P, Z = cfg.channels[-1], cfg.head_channels, cfg.feature_points, cfg.latent
    mlp_p = C * H + H + H * H + H + 4 * H          # 2 linear + 2 BN (γ, β per layer)
    mlp_m = P * A_ROT * (C * H + H * H)
    rows.append({"name": "pose head", "params": mlp_p + H * 7 + 7, "macs": mlp_m + A_ROT * H * 7})
    rows.append({"name": "invariant head", "params": mlp_p + (H + 3) * Z + Z + 2 * Z,
                 "macs": mlp_m + P * A_ROT * (H + 3) * Z})
    return rows + _tail_costs(cfg, partial)


def _tail_costs(cfg: ModelConfig, partial: bool) -> list:
    """Decoder and hypothesis-score rows (shared by both backbones)."""
    dims = (cfg.latent,) + tuple(cfg.decoder_hidden) + (3 * cfg.num_canonical_points,)
    dec_p = sum(a * b + b for a, b in zip(dims[:-1], dims[1:]))
    n_score = cfg.score_points if 0 < cfg.score_points < cfg.num_points else cfg.num_points
    score = A_ROT * n_score * cfg.num_canonical_points * 3 * (1 if partial else 2)
    return [{"name": "decoder", "params": dec_p, "macs": sum(a * b for a, b in zip(dims[:-1], dims[1:]))},
            {"name": "hypothesis scores", "params": 0, "macs": score}]


def _quotient_layer_costs(cfg: ModelConfig, partial: bool) -> list:
    """Cost rows of a quotient (12-vertex) backbone and its heads (``equipose.train.quotient``)."""
    V, KC, VC, K = 12, 5, 4, 13
    rows = []
    for i, L in enumerate(cfg.layers):
        P2, nn = L.points_out, L.neighbours
        params = (KC * L.c_in * L.c_out + L.c_out) + (L.c_out * VC * L.c_out + L.c_out) \
            + ((L.c_in * L.c_out + L.c_out) if i > 0 else 0)
        macs = (P2 * nn * K * 5                         # hat weights
                + P2 * K * nn * V * L.c_in               # neighbour aggregation
                + P2 * V * KC * L.c_in * L.c_out         # inter dense matmul
                + P2 * V * L.c_out * VC * L.c_out        # intra dense matmul
                + P2 * V * V * VC * L.c_out              # intra class sum
                + (P2 * V * L.c_in * L.c_out if i > 0 else 0))
        rows.append({"name": f"block{i // 2}.layer{i % 2} ({L.c_in}→{L.c_out}, {L.points_in}→{P2} pts, nn {nn}, 12 vertices)",
                     "params": params, "macs": macs})
    C, H, P, Z = cfg.channels[-1], cfg.head_channels, cfg.feature_points, cfg.latent
    mlp_p = C * H + H + H * H + H + 4 * H
    mlp_m = P * V * (C * H + H * H)
    rows.append({"name": "pose head", "params": mlp_p + 2 * H * H + H + H * 7 + 7,
                 "macs": mlp_m + A_ROT * (2 * H * H + H * 7)})
    rows.append({"name": "invariant head", "params": mlp_p + (H + 2) * Z + Z + 2 * Z,
                 "macs": mlp_m + P * V * (H + 2) * Z})
    return rows + _tail_costs(cfg, partial)


def total_macs(cfg, partial: bool = True) -> int:
    return int(sum(r["macs"] for r in layer_costs(cfg, partial)))


def count_params(cfg) -> int:
    return int(sum(r["params"] for r in layer_costs(cfg)))
