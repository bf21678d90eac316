"""Assemble the edge-preset table (docs/benchmarks.md) from measured JSON files.

Inputs (all produced by commands listed in docs/benchmarks.md):
    docs/results/edge/<preset>.json        ``equipose eval ... --json`` after the equal-budget training run
    docs/results/edge/bench_<preset>.json  ``equipose bench --model <preset>.onnx --json`` (fp32, int8, torch, icp)
    runs/edge/<preset>/latest.pt           training summary (steps done, s/step) — optional
Usage: python tools/bench/edge_report.py edge-a edge-b tiny paper > /tmp/table.md
"""
from __future__ import annotations

import json
import pathlib
import sys

from equipose.core.presets import count_params, total_macs

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _load(p):
    p = ROOT / p
    return json.loads(p.read_text()) if p.is_file() else None


def _steps(preset):
    ck = ROOT / f"runs/edge/{preset}/latest.pt"
    if not ck.is_file():
        return None, None
    import torch
    c = torch.load(ck, map_location="cpu", weights_only=True)
    return c.get("step"), (c.get("training") or {}).get("seconds_per_step_median")


def main(presets):
    print("| preset | params | GMAC | steps in budget | s/step | rot median ° | 5° acc | ORT fp32 p50 ms (e2e) | "
          "int8 p50 ms | torch p50 ms | ICP-60 p50 ms | × torch | × ICP |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for p in presets:
        ev, bench = _load(f"docs/results/edge/{p}.json"), _load(f"docs/results/edge/bench_{p}.json")
        steps, sps = _steps(p)
        ours = next((r for r in (ev or {}).get("rows", []) if r["method"] == "equipose"), None)
        rows = {r["backend"]: r for r in (bench or {}).get("rows", []) if "p50_ms" in r}
        f = lambda b: f"{rows[b]['p50_ms']:.1f}" if b in rows else "–"  # noqa: E731
        fp = rows.get("onnxruntime-fp32")
        ratio = lambda b: f"{rows[b]['p50_ms'] / fp['p50_ms']:.1f}" if fp and b in rows else "–"  # noqa: E731
        print(f"| {p} | {count_params(p):,} | {total_macs(p) / 1e9:.2f} | {steps if steps is not None else '–'} | "
              f"{sps:.2f} | " if sps else f"| {p} | {count_params(p):,} | {total_macs(p) / 1e9:.2f} | – | – | ", end="")
        print(f"{ours['rot_median_deg']:.1f} | {ours['acc_5deg']:.3f} | " if ours else "– | – | ", end="")
        print(f"{f('onnxruntime-fp32')} | {f('onnxruntime-int8')} | {f('torch')} | {f('icp60')} | "
              f"{ratio('torch')} | {ratio('icp60')} |")


if __name__ == "__main__":
    main(sys.argv[1:] or ["edge-a", "edge-b", "tiny", "paper"])
