"""Markdown tables of the shipped models (issue 7): our test metrics stored in each file's metadata (written by
``equipose eval --model M --store-metrics``), ICP-60 from the same command, and the paper's Table 1 / Table 2 rows.

Usage: python tools/release/models_table.py [--precision fp32|int8|all] [--scoreboard]
"""
from __future__ import annotations

import argparse
import pathlib

from equipose.models import model_cards

# Li et al., NeurIPS'21: Table 1 (complete, rotation mean / median / 5° acc) and Table 2 (partial) — "Ours" and
# "ICP + template shape" rows.
PAPER = {
    ("airplane", "complete"): {"ours": (23.09, 1.66, 0.87), "icp": (8.11, 1.22, 0.90)},
    ("car", "complete"): {"ours": (17.24, 2.13, 0.89), "icp": (22.76, 2.94, 0.69)},
    ("chair", "complete"): {"ours": (7.05, 4.55, 0.56), "icp": (88.92, 96.28, 0.10)},
    ("sofa", "complete"): {"ours": (8.87, 3.22, 0.68), "icp": (39.00, 9.69, 0.28)},
    ("bottle", "complete"): {"ours": (4.42, 0.83, 0.98), "icp": (76.11, 54.42, 0.04)},
    ("airplane", "partial"): {"ours": (3.31, 1.46, 0.95), "icp": (14.7, 1.54, 0.83)},
    ("car", "partial"): {"ours": (124.9, 177.3, 0.12), "icp": (87.4, 15.0, 0.36)},
    ("chair", "partial"): {"ours": (10.4, 3.84, 0.62), "icp": (68.19, 13.47, 0.29)},
    ("sofa", "partial"): {"ours": (72.2, 7.9, 0.40), "icp": (115.0, 165.4, 0.11)},
    ("bottle", "partial"): {"ours": (46.8, 2.3, 0.71), "icp": (26.11, 1.50, 0.81)},
}


def _triple(m: dict) -> str:
    if not m:
        return "–"
    return f"{m['rot_mean_deg']:.2f} / {m['rot_median_deg']:.2f} / {m['acc_5deg']:.2f}"


def _plain(stem: str) -> str:
    """The plain network's row (``--refine 0``) from docs/results/models/STEM.norefine.txt: mean / median / 5° (flip)."""
    path = pathlib.Path("docs/results/models") / f"{stem}.norefine.txt"
    if not path.is_file():
        return "–"
    for line in path.read_text().splitlines():
        parts = line.split()
        if parts and parts[0] == "equipose":
            mean, med, acc, flip = float(parts[1]), float(parts[2]), float(parts[5]), float(parts[7])
            return f"{mean:.2f} / {med:.2f} / {acc:.2f} ({flip:.2f})"
    return "–"


def _beats(m: dict, paper: tuple | None) -> str:
    if not m or not paper:
        return "–"
    ok = m["rot_median_deg"] <= paper[1] and m["acc_5deg"] >= paper[2]
    return "**yes**" if ok else "no"


def scoreboard() -> None:
    """One row per (category, test set): paper, ICP-60, plain network and default pipeline, fp32 and int8."""
    cards = {c["name"]: c for c in model_cards() if not c["random_init"]}
    print("| model | paper ours | paper ICP | ICP-60 (our run) | fp32 plain (flip) | fp32 default (flip) | "
          "int8 plain (flip) | int8 default (flip) | beats paper fp32 / int8 | steps |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, c in sorted(cards.items()):
        if c["precision"] != "fp32":
            continue
        m, q = c["metrics"], (cards.get(name + ".int8") or {}).get("metrics", {})
        test_mode = m.get("test_set", "–").split(" ")[0].split("/")[-1]
        paper = PAPER.get((c["category"], test_mode))
        fmt = lambda d: f"{_triple(d)} ({d['flip_rate']:.2f})" if d and "flip_rate" in d else _triple(d)  # noqa: E731
        print(f"| `{name}` | {' / '.join(f'{v:g}' for v in paper['ours']) if paper else '–'} | "
              f"{' / '.join(f'{v:g}' for v in paper['icp']) if paper else '–'} | {fmt(m.get('icp60', {}))} | "
              f"{_plain(name)} | {fmt(m)} | {_plain(name + '.int8')} | {fmt(q)} | "
              f"{_beats(m, paper['ours'] if paper else None)} / {_beats(q, paper['ours'] if paper else None)} | "
              f"{c['training'].get('step', '–')} |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--precision", default="all", choices=["fp32", "int8", "all"])
    ap.add_argument("--scoreboard", action="store_true", help="paper / ICP-60 / plain / default, fp32 and int8")
    args = ap.parse_args(argv)
    if args.scoreboard:
        scoreboard()
        return 0
    print("| model | category | network | test set | precision | MB | train steps | ours: mean / median / 5° | flip | "
          "ICP-60 (same run) | paper ours | paper ICP |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for c in model_cards():
        if c["random_init"] or (args.precision != "all" and c["precision"] != args.precision):
            continue
        m = c["metrics"]
        test = m.get("test_set", "–").split(" ")[0]                          # e.g. "cup/partial"
        test_mode = test.split("/")[-1] if "/" in test else c["mode"]
        paper = PAPER.get((c["category"], test_mode), {})
        p_ours = " / ".join(f"{v:g}" for v in paper["ours"]) if paper else "–"
        p_icp = " / ".join(f"{v:g}" for v in paper["icp"]) if paper else "–"
        flip = f"{m['flip_rate']:.2f}" if "flip_rate" in m else "–"
        steps = str(c["training"].get("step", "–"))
        if (c["training"].get("config") or {}).get("init"):
            steps += " (warm start)"                                        # continued from another run's weights
        print(f"| `{c['name']}` | {c['category']} | {c['mode']} | {test_mode} | {c['precision']} | {c['size_mb']:.2f} | "
              f"{steps} | {_triple(m)} | {flip} | {_triple(m.get('icp60', {}))} | "
              f"{p_ours} | {p_icp} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
