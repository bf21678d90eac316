"""``equipose models``: the models shipped with the package (or any given .onnx files) and their metadata."""
from __future__ import annotations

import json

__all__ = ["add_arguments", "run"]


def add_arguments(p):
    p.add_argument("paths", nargs="*", help=".onnx files to describe (default: the bundled models)")
    p.add_argument("--json", action="store_true",
                   help="print JSON: [{name, path, category, mode, preset, precision, size_mb, metrics, ...}]")


def _fmt(x, spec: str) -> str:
    return format("-", ">" + spec.split(".")[0].rstrip("d")) if x is None else format(x, spec)


def run(args) -> int:
    from equipose.models import model_cards

    cards = model_cards(args.paths or None)
    if args.json:
        print(json.dumps(cards, indent=1, default=str))
        return 0
    if not cards:
        print("no models")
        return 0
    print(f"{'name':28s} {'category':9s} {'mode':8s} {'preset':7s} {'prec':5s} {'MB':>5s} {'symmetry':14s} "
          f"{'rot med':>8s} {'5°':>5s} {'ICP med':>8s} {'steps':>6s}")
    for c in cards:
        m, icp = c["metrics"], c["metrics"].get("icp60", {})
        name = c["name"] + (" (random)" if c["random_init"] else "")
        print(f"{name:28s} {c['category']:9s} {c['mode']:8s} {c['preset']:7s} {c['precision']:5s} {c['size_mb']:5.2f} "
              f"{c['result_symmetry']:14s} {_fmt(m.get('rot_median_deg'), '8.2f')} {_fmt(m.get('acc_5deg'), '5.2f')} "
              f"{_fmt(icp.get('rot_median_deg'), '8.2f')} {_fmt(c['training'].get('step'), '6d')}")
    print("symmetry: what the results carry (continuous:z = free about z; 'none (handle)' = full 6D through the "
          "handle stage)")
    print("rot med / 5°: the model's own test metrics (equipose eval --store-metrics); ICP med: ICP-60 in the same run")
    return 0
