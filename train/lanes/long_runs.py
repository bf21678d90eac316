"""Training that accumulates across sessions: a tracked folder of resumable checkpoints with a manifest each.

Layout (``train/state/`` in the repository, committed):
    <name>/latest.pt       checkpoint of ``train/fitting/checkpoint.py`` (weights, Adam state, step)
    <name>/config.json     the ``TrainConfig`` that ``equipose train --out <dir> --resume`` continues with
    <name>/manifest.json   {"name", "role", "category", "mode", "preset", "steps", "data_version", "command",
                           "teacher", "history": [{"date", "steps_before", "steps_after", "minutes", "val": ...}]}

``<name>`` is the shipped model's name (``sdk/models/<name>.onnx``), or a candidate's whose manifest names the model
it may replace (``"candidate_for"``: ``chair-partial-qw`` is ``chair-partial`` widened to ``edge-qw`` by
``python -m equipose.train.network.widen``). A complete-shape model is a *teacher*; a partial-view model is a *student*
distilled from ``<category>-complete`` in the same folder.

Commands (``python -m equipose.train.lanes.long_runs ...``):
    seed NAME ...            recover the shipped ONNX networks into resumable checkpoints
                             (``equipose.train.network.onnx_weights``)
    run --lane A,B,C --minutes M [--slice S] [--snapshots DIR [--snapshot-every SEC]]
    slice NAME --minutes M
                             resume each named model for S minutes in turn until M minutes are spent (one process
                             per core: torch uses 1 thread); ``--snapshots`` keeps a copy of each new ``latest.pt``
                             as ``DIR/<name>/<step>.pt`` (checked every SEC seconds, default 120) for weight
                             averaging (``python -m equipose.train.lanes.averaging``)
    adopt NAME RUN_DIR       start tracking a model trained with ``equipose train --out RUN_DIR``
    show                     print every manifest (steps, data version, last validation)
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import hashlib
import json
import pathlib
import sys
import time

import numpy as np

__all__ = ["STATE_DIR", "seed_model", "adopt_run", "run_slice", "run_lane", "data_version", "read_manifest"]

REPO = pathlib.Path(__file__).resolve().parents[2]
STATE_DIR = REPO / "train" / "state"
MODELS_DIR = REPO / "sdk" / "models"


def data_version(root, category: str) -> str:
    """Short hash of the category's ModelNet alignment file (changes when the shared data is re-aligned)."""
    p = pathlib.Path(root) / "modelnet40_npy1024" / category / "alignment.json"
    if not p.is_file():
        return "none"
    return hashlib.sha256(p.read_bytes()).hexdigest()[:12]


def read_manifest(folder) -> dict:
    p = pathlib.Path(folder) / "manifest.json"
    return json.loads(p.read_text()) if p.is_file() else {}


def _write_json(path: pathlib.Path, obj) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj, indent=1) + "\n")
    tmp.replace(path)


def _calibration_inputs(root, category: str, partial: bool, n: int, count: int = 64, seed: int = 0) -> np.ndarray:
    """[count, n, 3] model-unit training-like inputs for BatchNorm statistics: complete clouds, or the half of each
    facing a random direction (a cheap stand-in for a rendered partial view)."""
    from equipose.core.geometry import farthest_point_order, random_rotations
    from equipose.train.data.modelnet import MODELNET_SCALE, load_complete
    clouds, _ = load_complete(root, category, "train")
    rng = np.random.default_rng(seed)
    out = np.empty((count, n, 3), np.float32)
    Rs = random_rotations(count, rng)
    for k in range(count):
        c = clouds[rng.integers(len(clouds))] / MODELNET_SCALE @ Rs[k].T               # [1024, 3]
        if partial:
            c = c[c[:, 2] < np.median(c[:, 2])]                                          # near half (camera at −z)
        c = c - c.mean(0)
        out[k] = c[farthest_point_order(c, n)] if len(c) >= n else c[rng.integers(0, len(c), n)]
    return out


def seed_model(name: str, *, state_dir=STATE_DIR, models_dir=MODELS_DIR, data_root=None,
               overwrite=False) -> pathlib.Path:
    """Recover ``models_dir/<name>.onnx`` into ``state_dir/<name>/`` (checkpoint, config, manifest)."""
    import torch
    from equipose.train.fitting.checkpoint import save_checkpoint, model_from_checkpoint
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.network.onnx_weights import checkpoint_from_onnx
    from equipose.train.fitting.config import TrainConfig
    root = pathlib.Path(data_root or default_data_root())
    folder = pathlib.Path(state_dir) / name
    if (folder / "latest.pt").is_file() and not overwrite:
        return folder / "latest.pt"
    onnx_path = pathlib.Path(models_dir) / f"{name}.onnx"
    probe = checkpoint_from_onnx(onnx_path)
    cat, partial = probe["category"], bool(probe["partial"])
    x = _calibration_inputs(root, cat, partial, probe["model_config"]["num_points"]) \
        if (root / "modelnet40_npy1024" / cat).is_dir() else None
    ck = checkpoint_from_onnx(onnx_path, x)
    model, _ = model_from_checkpoint(ck)
    folder.mkdir(parents=True, exist_ok=True)
    old = ck["training"].get("config", {})
    mode = "partial" if partial else "complete"
    cfg = TrainConfig(category=cat, mode=mode, preset=ck["model_config"]["name"], steps=ck["step"],
                      out=f"train/state/{name}", views=int(old.get("views", 10)), val_every=1000, ckpt_every=200,
                      teacher=f"train/state/{cat}-complete/latest.pt" if partial else "",
                      teacher_refine=int(old.get("teacher_refine", 5)), lr=float(old.get("lr", 5e-4)))
    save_checkpoint(folder / "latest.pt", model, category=cat, scale=ck["scale"], symmetry=ck["symmetry"],
                    step=ck["step"], calibration=ck["calibration"], training=ck["training"], metrics=ck["metrics"])
    _write_json(folder / "config.json", dataclasses.asdict(cfg))
    total = sum(int(h.get("steps", 0)) for h in ck["training"].get("lineage", [])) or ck["step"]
    _write_json(folder / "manifest.json", {
        "name": name, "role": "student" if partial else "teacher", "category": cat, "mode": mode,
        "preset": cfg.preset, "steps": int(total), "step_counter": int(ck["step"]),
        "data_version": data_version(root, cat), "teacher": f"{cat}-complete" if partial else None,
        "command": f"equipose train --out train/state/{name} --resume --steps N",
        "history": [{"date": datetime.date.today().isoformat(), "event": f"recovered from sdk/models/{name}.onnx",
                     "steps_after": int(total)}]})
    del torch
    return folder / "latest.pt"


def adopt_run(name: str, run_dir, *, state_dir=STATE_DIR, overwrite: bool = False) -> pathlib.Path:
    """Start tracking a model trained in ``run_dir`` (``latest.pt`` + ``config.json`` of ``equipose train``)."""
    import shutil
    import torch
    run_dir, folder = pathlib.Path(run_dir), pathlib.Path(state_dir) / name
    if (folder / "manifest.json").exists() and not overwrite:
        raise FileExistsError(f"{folder} is tracked already; pass --overwrite to replace it")
    folder.mkdir(parents=True, exist_ok=True)
    cfg = json.loads((run_dir / "config.json").read_text())
    ck = torch.load(run_dir / "latest.pt", map_location="cpu", weights_only=True)
    distilled = cfg["mode"] == "partial" and bool(cfg.get("teacher"))   # a student, or self-supervised on partials
    root = cfg.get("data_root") or _default_root()
    cfg.update(out=f"train/state/{name}", data_root="", cache_dir="", steps=int(ck["step"]), minutes=0.0,
               val_every=1000, init="",
               teacher=f"train/state/{cfg['category']}-complete/latest.pt" if distilled else "")
    shutil.copyfile(run_dir / "latest.pt", folder / "latest.pt")
    _write_json(folder / "config.json", cfg)
    _write_json(folder / "manifest.json", {
        "name": name, "category": cfg["category"], "mode": cfg["mode"],
        "role": "student" if distilled else ("teacher" if cfg["mode"] == "complete" else "self-supervised"),
        "preset": cfg["preset"], "steps": int(ck["step"]), "step_counter": int(ck["step"]),
        "data_version": data_version(root, cfg["category"]),
        "teacher": f"{cfg['category']}-complete" if distilled else None,
        "command": f"equipose train --out train/state/{name} --resume --steps N",
        "history": [{"date": datetime.date.today().isoformat(), "event": f"adopted from {run_dir.name}",
                     "steps_after": int(ck["step"])}]})
    return folder / "latest.pt"


def _default_root():
    from equipose.train.data.modelnet import default_data_root
    return default_data_root()


def run_slice(name: str, minutes: float, *, state_dir=STATE_DIR, data_root=None, cache_dir=None,
              batch_size: int | None = None, log=print) -> dict:
    """Resume ``name`` for ``minutes`` of training steps; update its manifest; return the last validation record.
    ``batch_size`` overrides the config's for this slice only (e.g. a larger batch on a lent GPU)."""
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.fitting.config import TrainConfig
    from equipose.train.fitting.trainer import train
    folder = pathlib.Path(state_dir) / name
    man = read_manifest(folder)
    cfg = TrainConfig.from_sources(str(folder / "config.json"))
    root = data_root or cfg.data_root or str(default_data_root())
    before = int(man.get("step_counter", 0))
    repo = pathlib.Path(state_dir).resolve().parents[1]          # config paths are relative to the repository root
    teacher = cfg.teacher
    if teacher and not pathlib.Path(teacher).is_absolute():
        teacher = str(repo / teacher)
    cfg = dataclasses.replace(cfg, out=str(folder), steps=before + 1_000_000, minutes=float(minutes),
                              val_every=10 ** 9, data_root=str(root), teacher=teacher,
                              cache_dir=str(cache_dir or cfg.cache_dir or ""),
                              batch_size=int(batch_size or cfg.batch_size))
    t0 = time.time()
    durable = (folder / "config.json").read_text()                  # the trainer writes the slice's own config there
    try:
        ck_path = train(cfg, resume=True, log=log)
    finally:
        (folder / "config.json").write_text(durable)                # keep repository-relative paths and options
    import torch
    ck = torch.load(ck_path, map_location="cpu", weights_only=True)
    after = int(ck["step"])
    val = (ck.get("training", {}).get("history") or [{}])[-1]
    man["steps"] = int(man.get("steps", before)) + (after - before)
    man["step_counter"] = after
    man["data_version"] = data_version(root, cfg.category)
    man.setdefault("history", []).append({
        "date": datetime.date.today().isoformat(), "steps_before": before, "steps_after": after,
        "minutes": round((time.time() - t0) / 60.0, 1), "batch_size": cfg.batch_size,
        "device": str(ck.get("training", {}).get("device", "")),
        "val_rot_median_deg": val.get("val_rot_median_deg"), "val_acc_5deg": val.get("val_acc_5deg")})
    _write_json(folder / "manifest.json", man)
    return val


def run_lane(names: list, minutes: float, slice_minutes: float, *, state_dir=STATE_DIR, cache_dir=None,
             snapshots=None, snapshot_every: float = 120.0, log=print) -> None:
    """Round-robin ``run_slice`` over ``names`` until ``minutes`` of wall time have passed; with ``snapshots`` (a
    folder) a ``SnapshotCopier`` keeps each saved step there."""
    from equipose.train.lanes.snapshots import SnapshotCopier
    end = time.time() + 60.0 * minutes
    copier = SnapshotCopier(names, snapshots, state_dir=state_dir, every=snapshot_every).start() if snapshots else None
    k = 0
    try:
        while time.time() + 60.0 * min(2.0, slice_minutes) < end:
            name = names[k % len(names)]
            left = (end - time.time()) / 60.0
            val = run_slice(name, min(slice_minutes, max(1.0, left - 1.0)), state_dir=state_dir,
                            cache_dir=cache_dir, log=log)
            log(f"[lane] {name}: val median {val.get('val_rot_median_deg')}  5° {val.get('val_acc_5deg')}")
            k += 1
    finally:
        if copier is not None:
            copier.stop()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m equipose.train.lanes.long_runs", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("seed", help="recover shipped ONNX networks into resumable checkpoints")
    s.add_argument("names", nargs="+")
    s.add_argument("--overwrite", action="store_true")
    r = sub.add_parser("run", help="a lane: resume each named model in turn, one slice at a time")
    r.add_argument("--lane", required=True, help="comma-separated model names")
    r.add_argument("--minutes", type=float, required=True, help="wall-clock minutes for the whole lane")
    r.add_argument("--slice", type=float, default=20.0, help="minutes per slice (default 20)")
    r.add_argument("--cache-dir", help="render cache folder (default: data_cache/ beside the package)")
    r.add_argument("--snapshots", help="keep a copy of each saved step here (DIR/<name>/<step>.pt) for averaging")
    r.add_argument("--snapshot-every", type=float, default=120.0, help="seconds between checks (default 120)")
    o = sub.add_parser("slice", help="one slice of one model (e.g. on a lent GPU)")
    o.add_argument("name")
    o.add_argument("--minutes", type=float, required=True)
    o.add_argument("--cache-dir")
    o.add_argument("--batch-size", type=int, help="this slice only (default: the model's config)")
    a = sub.add_parser("adopt", help="start tracking a run of equipose train --out RUN_DIR")
    a.add_argument("name")
    a.add_argument("run_dir")
    a.add_argument("--overwrite", action="store_true")
    sub.add_parser("show", help="print every manifest")
    for p in (s, r, o, a):
        p.add_argument("--state-dir", default=str(STATE_DIR))
    args = ap.parse_args(argv)
    import signal
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))       # a stopped lane still restores config.json (finally)
    state = pathlib.Path(getattr(args, "state_dir", STATE_DIR))
    if args.cmd == "seed":
        for n in args.names:
            print(n, "->", seed_model(n, state_dir=state, overwrite=args.overwrite))
    elif args.cmd == "adopt":
        print(args.name, "->", adopt_run(args.name, args.run_dir, state_dir=state, overwrite=args.overwrite))
    elif args.cmd == "slice":
        print(args.name, run_slice(args.name, args.minutes, state_dir=state, cache_dir=args.cache_dir,
                                   batch_size=args.batch_size))
    elif args.cmd == "run":
        run_lane([n.strip() for n in args.lane.split(",") if n.strip()], args.minutes, args.slice, state_dir=state,
                 cache_dir=args.cache_dir, snapshots=args.snapshots, snapshot_every=args.snapshot_every)
    else:
        for m in sorted(state.glob("*/manifest.json")):
            man = json.loads(m.read_text())
            last = man.get("history", [{}])[-1]
            print(f"{man['name']:<20} {man['role']:<8} steps {man['steps']:>7}  data {man['data_version']}  "
                  f"last {last.get('date')} val {last.get('val_rot_median_deg')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
