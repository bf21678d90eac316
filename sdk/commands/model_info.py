"""``equipose model-info --preset P``: parameters and multiply-accumulates per layer and in total (analytic)."""
from __future__ import annotations

import json

from equipose.core.presets import get_preset, layer_costs, list_presets


def add_arguments(p):
    p.add_argument("--preset", default="paper", help=f"one of: {', '.join(list_presets())}")
    p.add_argument("--mode", choices=["partial", "complete"], default="partial",
                   help="score direction (complete adds the reverse chamfer)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")


def run(args) -> int:
    cfg = get_preset(args.preset)
    rows = layer_costs(cfg, partial=args.mode == "partial")
    total_p, total_m = sum(r["params"] for r in rows), sum(r["macs"] for r in rows)
    if args.json:
        print(json.dumps({"preset": cfg.name, "num_points": cfg.num_points, "rows": rows,
                          "params": total_p, "macs": total_m}, indent=1))
        return 0
    print(f"preset {cfg.name}: {cfg.description}")
    print(f"input points {cfg.num_points}, canonical points {cfg.num_canonical_points}, "
          f"kernel points {cfg.kernel_points}, mode {args.mode}")
    print(f"{'layer':<52} {'params':>10} {'MMAC':>10}")
    for r in rows:
        print(f"{r['name']:<52} {r['params']:>10,} {r['macs'] / 1e6:>10.1f}")
    print(f"{'total':<52} {total_p:>10,} {total_m / 1e6:>10.1f}  ({total_m / 1e9:.2f} GMAC)")
    return 0
