"""One figure and one table from the JSON files of ``python -m equipose.train.evaluation.confidence --json``:
held-out reliability diagrams of every model side by side, and per model AUROC / ECE / confident-wrong counts of the
calibrated confidence next to the selection margin's, plus the right rate and box-vs-mask medians of tabletop rows.

Usage: python tools/bench/confidence_figure.py RUN.json [RUN.json ...] --png F --summary F.json
"""
from __future__ import annotations

import argparse
import json
import pathlib

import numpy as np


def _median(rows, key, **where):
    vals = [r[key] for r in rows if all(r.get(k) == v for k, v in where.items())]
    return float(np.median(vals)) if vals else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--png", required=True)
    ap.add_argument("--summary", required=True, help="compact JSON: calibration + held-out summary per model")
    a = ap.parse_args(argv)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runs = [(pathlib.Path(p).stem, json.loads(pathlib.Path(p).read_text())) for p in a.runs]
    cols = 5
    fig, axes = plt.subplots((len(runs) + cols - 1) // cols, cols, figsize=(2.6 * cols, 2.6 * ((len(runs) + 4) // 5)),
                             squeeze=False)
    out = {}
    print("| model | results | right | AUROC | (margin) | ECE | (margin) | confident-wrong | (margin) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for ax, (name, run) in zip(axes.ravel(), runs):
        s, rows = run["summary"], run["rows"]
        t = s["reliability"]
        ax.plot([0, 1], [0, 1], "k:", lw=0.8)
        ax.plot([b["mean_confidence"] for b in t], [b["right_rate"] for b in t], "o-", ms=3)
        ax.set_title(f"{name}\nAUROC {s['auroc']:.2f}  ECE {s['ece']:.2f}", fontsize=8)
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1)
        ax.tick_params(labelsize=7)
        print(f"| {name} | {s['n']} | {s['right_rate']:.2f} | {s['auroc']:.3f} | {s['margin_auroc']:.3f} | "
              f"{s['ece']:.3f} | {s['margin_ece']:.3f} | {s['confident_wrong']} | {s['margin_confident_wrong']} |")
        entry = {"calibration": run["calibration"], "held_out": {k: v for k, v in s.items()}}
        if rows and rows[0]["prompt"] != "points":
            entry["axis_median_deg"] = {f"{p}/{u}": _median(rows, "axis_err", prompt=p, up=u)
                                        for p in ("box", "mask") for u in ("none", "plane")}
            entry["right_rate"] = {f"{p}/{u}": float(np.mean([r["right"] for r in rows
                                                               if r["prompt"] == p and r["up"] == u]))
                                   for p in ("box", "mask") for u in ("none", "plane")}
        out[name] = entry
    for ax in axes.ravel()[len(runs):]:
        ax.axis("off")
    fig.supxlabel("confidence (held-out shapes)", fontsize=9)
    fig.supylabel("share right", fontsize=9)
    fig.tight_layout()
    fig.savefig(a.png, dpi=90)
    pathlib.Path(a.summary).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
