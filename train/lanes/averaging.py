"""Weight averaging of one run's checkpoints (stochastic weight averaging, SWA): the mean of snapshots taken along a
run at a steady learning rate sits nearer the middle of the basin the optimiser wanders in than any single snapshot.

Usage: ``python -m equipose.train.lanes.averaging OUT.pt SNAPSHOT.pt...`` (e.g. copies of a lane's ``latest.pt`` taken
every two minutes). The result keeps the newest snapshot's metadata (step, calibration, training record), carries the
averaged floating-point tensors (BatchNorm running statistics included) and no optimiser state; it calibrates,
exports and ships like any checkpoint. Snapshots of the same step are counted once (a copy loop that outlives its
lane, or a lane between two saves, copies one checkpoint many times; counting each copy would weight it that often).

What it gives the shipped students: docs/results/models/README.md (v0.13 onwards).
"""
from __future__ import annotations

import argparse
import sys

import torch

from equipose.core.errors import ConfigError
from equipose.train.fitting.checkpoint import load_checkpoint

__all__ = ["average_checkpoints", "main"]


def _same_weights(a: dict, b: dict) -> bool:
    sa, sb = a["state_dict"], b["state_dict"]
    return sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)


def average_checkpoints(paths: list) -> dict:
    """Checkpoint dicts of one architecture → one checkpoint: floating-point weights and buffers averaged over the
    snapshots, everything else (integer buffers, metadata) from the one with the highest step; optimiser dropped.
    Copies of a step already seen (same step, same weights) are skipped (``out["averaged"]["duplicates"]`` counts
    them). Raises ``ConfigError`` for an empty list, two different snapshots of one step, or snapshots of different
    architectures, categories or modes."""
    if not paths:
        raise ConfigError("average_checkpoints needs at least one checkpoint")
    by_step = {}                                                   # step → (path, checkpoint), first copy kept
    for p in paths:
        c = load_checkpoint(p)
        step = int(c.get("step", 0))
        if step not in by_step:
            by_step[step] = (p, c)
        elif not _same_weights(c, by_step[step][1]):
            raise ConfigError(f"{p} and {by_step[step][0]} are both step {step} but hold different weights; average "
                              "snapshots of one run only")
    ref = by_step[max(by_step)][1]
    for p, c in by_step.values():
        same = (c.get("model_config") == ref.get("model_config") and c.get("category") == ref.get("category")
                and c.get("partial") == ref.get("partial") and c["state_dict"].keys() == ref["state_dict"].keys())
        if not same:
            raise ConfigError(f"{p}: not a snapshot of the same network as the others (architecture, category, mode "
                              "or weights differ); average snapshots of one run only")
    cks = [c for _, c in by_step.values()]
    state = {}
    for k, v in ref["state_dict"].items():
        if v.is_floating_point():
            state[k] = torch.stack([c["state_dict"][k].to(torch.float64) for c in cks]).mean(0).to(v.dtype)
        else:
            state[k] = v.clone()
    out = dict(ref, state_dict=state, optimizer=None)
    out["averaged"] = {"count": len(cks), "steps": sorted(by_step), "duplicates": len(paths) - len(cks)}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m equipose.train.lanes.averaging", description=__doc__.splitlines()[0])
    ap.add_argument("out", help="the averaged checkpoint (.pt)")
    ap.add_argument("snapshots", nargs="+", help="checkpoints of one run")
    a = ap.parse_args(argv)
    ck = average_checkpoints(a.snapshots)
    torch.save(ck, a.out)
    dup = ck["averaged"]["duplicates"]
    print(f"averaged {ck['averaged']['count']} checkpoints (steps {ck['averaged']['steps'][0]}–"
          f"{ck['averaged']['steps'][-1]}{f'; {dup} of a step already counted skipped' if dup else ''}) → {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
