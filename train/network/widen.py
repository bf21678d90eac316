"""Function-preserving widening of a trained network's backbone (Net2WiderNet, Chen et al. 2016).

A student that underfits (it fits its training views hardly better than the test views) can continue as a wider
network without starting over: every backbone channel c of the narrow network becomes the channels c and c + C of
the wide one (same incoming weights and bias), and each layer that reads a duplicated channel splits that channel's
weights between the two copies (fractions α and 1 − α, drawn per weight). The wide network computes exactly what the
narrow one did — instance norm, LeakyReLU and the skip sum act per channel, so the copies stay equal — and the
random split gives the copies different gradients, so training pulls them apart.

Convention:
    Only the backbone's channel widths change (``ModelConfig.channels``); the heads, the latent and the decoder keep
    their sizes, and the heads' first layers read the wider backbone output. Both presets must agree on everything
    else (points, strides, radii, kernels, quotient layout), and each wide width must be a multiple of the narrow one.

Command:
    python -m equipose.train.network.widen IN.pt --preset edge-qw --out OUT.pt [--seed 0]
"""
from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import torch

from equipose.core.presets import ModelConfig, get_preset
from equipose.errors import ConfigError
from equipose.train.fitting.checkpoint import model_from_checkpoint, save_checkpoint
from equipose.train.network.model import EquiPoseNet

__all__ = ["widen_model", "widen_checkpoint", "SPLIT_RANGE"]

SPLIT_RANGE = (0.3, 0.7)          # the fraction α of a duplicated input's weight that its first copy keeps


def _check_compatible(narrow: ModelConfig, wide: ModelConfig) -> None:
    skip = {"name", "description", "channels"}

    def plain(cfg: ModelConfig) -> dict:                              # layer specs compared without their widths
        d = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in skip}
        if "layers" in d:
            d["layers"] = [{k: v for k, v in spec.items() if k not in ("c_in", "c_out")} for spec in d["layers"]]
        return d
    a, b = plain(narrow), plain(wide)
    diff = sorted(k for k in a if a[k] != b.get(k))
    if diff:
        raise ConfigError(f"cannot widen {narrow.name!r} into {wide.name!r}: they differ in {', '.join(diff)}, "
                          "not only in channel widths; choose a preset that only widens the backbone")
    pairs = list(zip(narrow.channels, wide.channels))
    if len(narrow.channels) != len(wide.channels) or any(w % n or w < n for n, w in pairs):
        raise ConfigError(f"cannot widen channels {tuple(narrow.channels)} into {tuple(wide.channels)}: "
                          "each wide width must be a multiple of the narrow one, layer by layer")


def _source(c_narrow: int, c_wide: int) -> np.ndarray:
    """Wide channel → the narrow channel it copies (c' mod C)."""
    return np.arange(c_wide) % c_narrow


def _widen(w: torch.Tensor, *, out_axis: int | None = None, out_src=None, in_axis: int | None = None, in_src=None,
           rng: np.random.Generator) -> torch.Tensor:
    """Copy output channels along ``out_axis``; copy and split input channels along ``in_axis``.
    ``*_src`` come from ``_source``: wide channel c' copies c' mod C, so it is copy number c' // C of C."""
    if out_axis is not None:
        w = w.index_select(out_axis, torch.as_tensor(out_src))
    if in_axis is not None:
        w = w.index_select(in_axis, torch.as_tensor(in_src))
        c_narrow = int(in_src.max()) + 1
        copies = len(in_src) // c_narrow
        view = [1] * w.dim()
        view[in_axis] = len(in_src)
        first = (np.arange(len(in_src)) < c_narrow).reshape(view)
        if copies == 2:          # one α per narrow weight: its two copies carry α and 1 − α of it
            narrow_shape = list(w.shape)
            narrow_shape[in_axis] = 1
            alpha = rng.uniform(*SPLIT_RANGE, size=narrow_shape)
            share = np.where(first, alpha, 1.0 - alpha)
        else:                    # one copy keeps the weight; more than two share it equally
            share = np.full(view, 1.0 / copies)
        w = w * torch.tensor(share, dtype=w.dtype)
    return w.contiguous()


def widen_model(model: EquiPoseNet, preset, seed: int = 0) -> EquiPoseNet:
    """A network of ``preset`` (wider backbone) computing the same outputs as ``model``.

    Layouts handled (``quotient``, ``layers``, ``model`` of this package): inter weight [K·Cin, Cout] (kernel- or
    class-major), intra weight [Cin, R·Cout] (quotient, class-major) or [R·Cin, Cout] (60 rotations), skip
    ``nn.Linear`` [Cout, Cin], the heads' first ``nn.Linear`` [H, C]. Raises ``ConfigError`` for presets that
    differ in more than channel widths.
    """
    narrow = model.config
    wide_cfg = get_preset(preset)
    _check_compatible(narrow, wide_cfg)
    rng = np.random.default_rng(seed)
    wide = EquiPoseNet(wide_cfg, partial=model.partial)
    sd = model.state_dict()                                           # read only: widened tensors are new
    out = dict(sd)
    c_prev_n, c_prev_w = None, None                                   # input widths of the current block
    for i, (cn, cw) in enumerate(zip(narrow.channels, wide_cfg.channels)):
        o_src = _source(cn, cw)
        i_src = None if c_prev_n is None else _source(c_prev_n, c_prev_w)
        p = f"blocks.{i}."
        w = sd[p + "inter.weight"]                                    # [K·Cin, Cout]
        k = w.shape[0] // (c_prev_n or 1)
        w = w.view(k, c_prev_n or 1, cn)
        w = _widen(w, out_axis=2, out_src=o_src, in_axis=None if i_src is None else 1, in_src=i_src, rng=rng)
        out[p + "inter.weight"] = w.reshape(k * (c_prev_w or 1), cw)
        out[p + "inter.bias"] = sd[p + "inter.bias"][o_src]
        w = sd[p + "intra.weight"]
        if narrow.quotient:                                           # [C, R·C] class-major (QuotientIntraConv)
            r = w.shape[1] // cn
            w = _widen(w.view(cn, r, cn), out_axis=2, out_src=o_src, in_axis=0, in_src=o_src, rng=rng)
            out[p + "intra.weight"] = w.reshape(cw, r * cw)
        else:                                                         # [R·C, C] neighbour-major (IntraSO3Conv)
            r = w.shape[0] // cn
            w = _widen(w.view(r, cn, cn), out_axis=2, out_src=o_src, in_axis=1, in_src=o_src, rng=rng)
            out[p + "intra.weight"] = w.reshape(r * cw, cw)
        out[p + "intra.bias"] = sd[p + "intra.bias"][o_src]
        if p + "skip.weight" in sd:
            out[p + "skip.weight"] = _widen(sd[p + "skip.weight"], out_axis=0, out_src=o_src, in_axis=1,
                                            in_src=i_src, rng=rng)
            out[p + "skip.bias"] = sd[p + "skip.bias"][o_src]
        c_prev_n, c_prev_w = cn, cw
    last_src = _source(c_prev_n, c_prev_w)
    for head in ("pose_head", "inv_head"):
        key = f"{head}.mlp.0.0.weight"                                # [H, C]
        out[key] = _widen(sd[key], in_axis=1, in_src=last_src, rng=rng)
    missing = set(wide.state_dict()) ^ set(out)
    if missing:
        raise ConfigError(f"widening does not cover the parameters {sorted(missing)[:6]} of preset {wide_cfg.name!r}")
    wide.load_state_dict(out)
    return wide.train(model.training)


def widen_checkpoint(src, preset, out, seed: int = 0) -> dict:
    """Write ``out``: the checkpoint ``src`` widened to ``preset``, step 0, no optimiser state (a fresh Adam)."""
    model, ck = model_from_checkpoint(src)
    wide = widen_model(model, preset, seed=seed)
    save_checkpoint(out, wide, category=ck["category"], scale=ck["scale"], symmetry=ck.get("symmetry", "none"),
                    step=0, training={"widened_from": {"preset": model.config.name, "step": int(ck["step"])}})
    return {"from": model.config.name, "to": wide.config.name, "step": int(ck["step"]),
            "params": (sum(p.numel() for p in model.parameters()), sum(p.numel() for p in wide.parameters()))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m equipose.train.network.widen", description=__doc__.split("\n")[0])
    ap.add_argument("checkpoint", help="trained checkpoint (.pt) of the narrow preset")
    ap.add_argument("--preset", required=True, help="wider preset, e.g. edge-qw")
    ap.add_argument("--out", required=True, help="checkpoint to write (step 0, fresh optimiser)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the random weight split")
    a = ap.parse_args(argv)
    info = widen_checkpoint(a.checkpoint, a.preset, a.out, seed=a.seed)
    print(f"{a.out}: {info['from']} → {info['to']} ({info['params'][0]:,} → {info['params'][1]:,} parameters), "
          f"from step {info['step']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
