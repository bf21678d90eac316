"""Accuracy of stage-option candidates on one model's test set, through the SDK (no ICP-60): the measurements behind
the ``default`` and ``fast`` profiles (``equipose.runtime.profiles``).

Usage: python tools/bench/profile_sweep.py MODEL CATEGORY MODE [--limit K] [--candidates JSON_FILE | --profiles]
  JSON_FILE: {"label": {stage: options}, ...}; --profiles: fast / default / accurate.
Prints one row per candidate: rotation mean / median (°), 5° accuracy, flip rate, SDK seconds for the test set.
"""
from __future__ import annotations

import argparse
import json

from equipose.train.evaluation.evaluate import evaluate


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model")
    ap.add_argument("category")
    ap.add_argument("mode", choices=["complete", "partial"])
    ap.add_argument("--limit", type=int)
    ap.add_argument("--candidates", help="JSON file {label: {stage: options}}")
    ap.add_argument("--profiles", action="store_true", help="the three named profiles")
    a = ap.parse_args(argv)
    runs = {p: (p, None) for p in ("fast", "default", "accurate")} if a.profiles else {}
    if a.candidates:
        with open(a.candidates) as f:
            runs.update({k: ("accurate", v) for k, v in json.load(f).items()})
    for label, (profile, stages) in runs.items():
        res = evaluate(category=a.category, mode=a.mode, model_path=a.model, limit=a.limit, icp_templates=0,
                       profile=profile, stages=stages, progress=False, log=lambda *_: None)
        row = res["rows"][0]
        print(f"{a.model:18s} {label:28s} mean {row['rot_mean_deg']:6.2f} med {row['rot_median_deg']:5.2f} "
              f"5° {row['acc_5deg']:.3f} flip {row['flip_rate']:.3f}  sdk {res['_info']['seconds']['ours']:.1f} s", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
