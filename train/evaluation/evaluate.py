"""Paper-style evaluation: ours (torch checkpoint or the exported ONNX through the SDK) next to ICP-60 + template.

Convention:
    Test samples come from ``data`` (``raw(i)``): points in metres (file units for ModelNet), GT pose x = R x_obj + t
    (metres), the instance's bbox diagonal. Rotation errors in degrees (symmetric categories: up-axis angle);
    translation errors ‖t̂ − t‖ divided by the bbox diagonal on ModelNet (as the paper), so "0.05" is 5 % of the
    diagonal. The checkpoint path feeds the model exactly what ``PoseEstimator`` does
    (``equipose.preprocess.prepare_points``: centroid-centred, scaled, FPS-ordered), then argmin-of-60 selection and
    the stored calibration.
    ICP-60 runs on the same points against 3 random training shapes (category frame, seeded); its row is the mean of
    the per-template rows, as the paper. Through the SDK, rows in brackets follow ours: the views whose handle was
    seen / hidden, the unflagged / flagged ones, and, for models with a turn classifier, "[either reading]": each
    view's pose or its ``flip_rotation``, whichever is nearer the truth (what a user who can try both gets).
    JSON: ``{"category", "mode", "n", "rows": [{method, rot_mean_deg, rot_median_deg, trans_mean, trans_median,
    acc_5deg, acc_5deg_005, flip_rate}]}`` (+ ``"details"`` under a separate key only when asked).
"""
from __future__ import annotations

import hashlib
import json
import pathlib
import time

import numpy as np

from equipose.preprocess import prepare_points
from equipose.core.errors import ConfigError
from equipose.core.geometry import farthest_point_order

from equipose.train.evaluation.calibration import apply_calibration
from equipose.train.data.datasets import ModelNetComplete, RenderedPartial
from equipose.train.data.modelnet import default_data_root, load_modelnet
from equipose.train.evaluation.icp import icp60
from equipose.eval.metrics import rotation_errors, row_keys, summarize, translation_errors

__all__ = ["test_dataset", "predict_checkpoint", "predict_onnx", "run_icp", "evaluate", "plot_percentiles",
           "metrics_for_metadata"]


def test_dataset(root, category: str, mode: str, num_points: int, limit: int | None = None, cache_dir=None,
                 views: int = 5):
    """The paper's test set: complete = 5 seeded rotations per test instance; partial = rendered test views."""
    if mode == "complete":
        return ModelNetComplete(root, category, "test", num_points, train=False, limit=limit)
    if mode == "partial":
        from equipose.train.data.render_cache import ensure_cache
        return RenderedPartial(ensure_cache(root, category, "test", cache_dir=cache_dir, limit=limit, views=views),
                               num_points, train=False)
    raise ConfigError(f"mode must be complete or partial, got {mode!r}")


# test instances whose ground-truth frame looks wrong (shared/data/SOURCES.md); report metrics with and without them
SUSPECT_TEST_INSTANCES = {"airplane": ("0629", "0637", "0662", "0664", "0679"), "sofa": ("0683",)}


def _instance_names(ds, root, category: str, mode: str, limit) -> list:
    """Instance names (``airplane_0629``) indexed like the samples' ``instance`` field."""
    if mode == "complete":
        return list(ds.ids)
    from equipose.train.data.render_cache import modelnet_shapes
    return [name for name, _, _ in modelnet_shapes(root, category, "test", "npy1024", limit)]


def predict_checkpoint(model, ckpt: dict, samples: list, batch_size: int = 16) -> tuple:
    """Torch model on the SDK's model input. Returns (R [S, 3, 3], t [S, 3] metres), calibrated."""
    from equipose.train.evaluation.inference import predict_torch
    scale = float(ckpt["scale"])
    preps = [prepare_points(s["points_m"], model.num_points, scale) for s in samples]
    R, t, _ = predict_torch(model, np.stack([p.model_points for p in preps]), batch_size)
    R, t = apply_calibration(R, t, ckpt.get("calibration"))
    t_m = np.stack([p.to_metres(ti) for p, ti in zip(preps, t)])
    return R, t_m


def predict_onnx(model, samples: list, batch_size: int = 16, refine="auto", up: str | None = None) -> tuple:
    """The exported model through ``equipose.PoseEstimator`` (what users run; ``model``: a path, or an estimator that
    is used as it is; ``refine``: its ICP re-scoring of the k best hypotheses). Returns (R, t metres, estimator,
    handle seen [S] bool or None for models without one, the results' symmetry — "none" once a handle stage made the
    pose full 6D). ``up="gt"``: the up prior with each sample's true up axis (what a level IMU or the table plane
    gives a user; ``equipose.runtime.upright``). Then: [S] bool, the results' ``ambiguous`` flags; last: [S, 3, 3]
    their ``flip_rotation`` (the other reading: models with a turn classifier), or None."""
    from equipose.runtime.estimator import PoseEstimator
    est = model if isinstance(model, PoseEstimator) else PoseEstimator(model, refine=refine)
    Rs, ts, seen, flagged, flips, sym = [], [], [], [], [], est.symmetry
    for i in range(0, len(samples), batch_size):
        chunk = samples[i:i + batch_size]
        ups = None if up is None else [s["rotation"][:, 2] for s in chunk]
        for r in est.predict_points_batch([s["points_m"] for s in chunk], up=ups):
            Rs.append(r.rotation)
            ts.append(r.translation)
            seen.append(r.handle_visible)
            flagged.append(r.ambiguous)
            flips.append(r.flip_rotation)
            sym = r.symmetry
    return (np.stack(Rs), np.stack(ts), est, None if est.handle is None else np.array(seen, bool), sym,
            np.array(flagged, bool), None if any(f is None for f in flips) or not flips else np.stack(flips))


def run_icp(samples: list, templates: list, bidirectional: bool, obs_points: int = 256, iters: int = 20,
            progress: bool = True) -> list:
    """[(R [S,3,3], t [S,3])] per template. Observations FPS-subsampled to ``obs_points``."""
    from tqdm import tqdm
    out = []
    for k, tmpl in enumerate(templates):
        Rs, ts = [], []
        for s in tqdm(samples, desc=f"icp60 template {k + 1}/{len(templates)}", disable=not progress, leave=False):
            x = s["points_m"]
            x = x[farthest_point_order(x, min(obs_points, len(x)))]
            R, t, _ = icp60(x, tmpl, iters=iters, bidirectional=bidirectional)
            Rs.append(R)
            ts.append(t)
        out.append((np.stack(Rs), np.stack(ts)))
    return out


def _cached_icp(samples: list, templates: list, cache_dir, *, log=print, **opts) -> list:
    """``run_icp`` with its poses kept on disk (the baseline does not depend on the model under test), keyed by the
    exact observations, templates and options (``equipose.train.data.cache_io.keyed_cache_path``)."""
    from equipose.train.data.cache_io import keyed_cache_path
    digest = hashlib.sha1()
    for a in [s["points_m"] for s in samples] + list(templates):
        digest.update(np.ascontiguousarray(a, np.float64).tobytes())
    settings = {k: v for k, v in opts.items() if k != "progress"}
    _, path = keyed_cache_path(cache_dir, "icp60", {**settings, "data": digest.hexdigest()})
    if path.is_file():
        z = np.load(path)
        log(f"ICP-60 poses from {path.name}")
        return [(z["R"][k], z["t"][k]) for k in range(len(z["R"]))]
    per = run_icp(samples, templates, **opts)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, R=np.stack([R for R, _ in per]), t=np.stack([t for _, t in per]))
    tmp.replace(path)
    return per


def _icp_template_clouds(root, category: str) -> list:
    """ICP-60 template candidates in the test samples' units: ModelNet train clouds (file units), or for tabletop
    categories the ModelNet source category resized to the middle of its metric radius range (metres)."""
    from equipose.train.data.tabletop import TABLETOP, modelnet_sources
    spec = TABLETOP.get(category)
    if spec is None:
        return list(load_modelnet(root, category, "train")[0])
    clouds, _ = modelnet_sources(root, category, "train")
    return [c * float(np.mean(spec.radius_m)) for c in clouds]


def _row(method, R, t, samples, symmetry, unsigned):
    R_gt = np.stack([s["rotation"] for s in samples])
    t_gt = np.stack([s["translation_m"] for s in samples])
    diag = np.array([s["diag_m"] for s in samples])
    r_err = rotation_errors(R, R_gt, symmetry, unsigned)
    t_err = translation_errors(t, t_gt, diag)
    return summarize(method, r_err, t_err), r_err, t_err


def evaluate(*, category: str, mode: str, checkpoint=None, model_path=None, data_root=None, limit: int | None = None,
             icp_templates: int = 3, icp_points: int = 256, icp_iters: int = 20, template_points: int = 512,
             icp_samples: int | None = None, refine=None, copies=None, exclude=(), up: str | None = None,
             seed: int = 0, cache_dir=None, progress: bool = True, log=print, profile: str = "default",
             stages: dict | None = None) -> dict:
    """Run both methods on one test set; returns the result dict (JSON layout above) plus ``_errors`` arrays.
    ``profile`` / ``stages``: the SDK's profile and stage options (``PoseEstimator(profile=..., stages=...)``)."""
    root = data_root or default_data_root()
    if (checkpoint is None) == (model_path is None):
        raise ConfigError("give exactly one of --checkpoint or --model")
    if up not in (None, "gt") or (up and checkpoint is not None):
        raise ConfigError(f"--up takes 'gt' (the true up axis as the up prior) and needs --model, got {up!r}")
    if (refine is not None or copies is not None) and checkpoint is not None:
        raise ConfigError("--refine and --copies apply to an exported model (--model), the SDK's re-scoring")
    if checkpoint is not None:
        from equipose.train.fitting.checkpoint import model_from_checkpoint
        model, ckpt = model_from_checkpoint(checkpoint)
        num_points, symmetry, scale = model.num_points, ckpt["symmetry"], float(ckpt["scale"])
        if ckpt["category"] != category:
            log(f"warning: checkpoint category {ckpt['category']!r} ≠ --category {category!r}")
        if bool(ckpt["partial"]) != (mode == "partial"):
            log(f"warning: checkpoint partial={ckpt['partial']} but --mode {mode}")
        if not ckpt.get("calibration"):
            log("warning: checkpoint has no calibration (identity); run 'equipose calibrate' first")
    else:
        from equipose.runtime.estimator import PoseEstimator
        est = PoseEstimator(model_path, refine="auto" if refine is None else refine,
                            copies="auto" if copies is None else copies, profile=profile, stages=stages)
        num_points, symmetry, scale = est.num_points, est.symmetry, est.scale
    unsigned = category == "can"
    ds = test_dataset(root, category, mode, num_points, limit=limit, cache_dir=cache_dir)
    samples = [ds.raw(i) for i in range(len(ds))]
    if exclude:                                                    # e.g. SUSPECT_TEST_INSTANCES[category]
        names = _instance_names(ds, root, category, mode, limit)
        drop = {k for k, nm in enumerate(names) if any(nm == e or nm.endswith("_" + e) for e in exclude)}
        samples = [sm for sm in samples if sm["instance"] not in drop]
        log(f"excluded {len(ds) - len(samples)} samples of {len(drop)} instance(s): "
            f"{', '.join(sorted(names[k] for k in drop))}")
    t0 = time.perf_counter()
    if checkpoint is not None:
        R, t = predict_checkpoint(model, ckpt, samples)
    else:
        R, t, est, seen, symmetry, flagged, flips = predict_onnx(est, samples, up=up)  # symmetry: the results'
        refine = est.refine
    ours_s = time.perf_counter() - t0
    name = "equipose" + ("+up(gt)" if up else f"+icp{refine}" if refine else "")
    if checkpoint is None and est.copies > 1:
        name += f"+copies{est.copies}"
    row, r_err, t_err = _row(name, R, t, samples, symmetry, unsigned)
    rows, errors = [row], {"equipose": (r_err, t_err)}
    splits = []
    if checkpoint is None and seen is not None:                    # handle models: the views whose handle was seen
        splits += [("handle seen", seen), ("handle hidden", ~seen)]
    if checkpoint is None:                                         # the views the SDK flagged ambiguous, and the rest
        splits += [("unflagged", ~flagged), ("flagged", flagged)]
    for label, m in splits:
        if m.any():
            sub = [sm for sm, k in zip(samples, m) if k]
            rows.append({**_row(f"{row['method']} [{label}]", R[m], t[m], sub, symmetry, unsigned)[0],
                         "fraction": float(m.mean())})
    if checkpoint is None and flips is not None:                   # the pose or its other reading, whichever is right
        f_err = rotation_errors(flips, np.stack([s["rotation"] for s in samples]), symmetry, unsigned)   # [S]
        either = np.where((f_err < r_err)[:, None, None], flips, R)            # [S, 3, 3]
        rows.append({**_row(f"{row['method']} [either reading]", either, t, samples, symmetry, unsigned)[0],
                     "fraction": 1.0})

    pick, trows, icp_set, icp_s = [], [], [], 0.0
    if icp_templates > 0:                                          # 0: ours only
        clouds = _icp_template_clouds(root, category)
        pick = np.random.default_rng(seed).choice(len(clouds), size=icp_templates, replace=False)
        templates = [clouds[i][farthest_point_order(clouds[i], template_points)].astype(np.float64) for i in pick]
        icp_idx = np.arange(len(samples))
        if icp_samples and icp_samples < len(samples):                # evenly spaced subset (cost control)
            icp_idx = np.linspace(0, len(samples) - 1, icp_samples).round().astype(int)
        icp_set = [samples[i] for i in icp_idx]
        t0 = time.perf_counter()
        per = _cached_icp(icp_set, templates, cache_dir, bidirectional=(mode == "complete"), obs_points=icp_points,
                          iters=icp_iters, progress=progress, log=log)
        icp_s = time.perf_counter() - t0
        r_all, t_all = [], []
        for Ri, ti in per:
            rw, re, te = _row("icp60", Ri, ti, icp_set, symmetry, unsigned)
            trows.append(rw)
            r_all.append(re)
            t_all.append(te)
        icp_row = {"method": "icp60", **{k: float(np.mean([r[k] for r in trows])) for k in row_keys()[1:]}}
        rows.append(icp_row)
        errors["icp60"] = (np.concatenate(r_all), np.concatenate(t_all))
    log(f"evaluated {len(samples)} samples: ours {ours_s:.1f} s; ICP-60 on {len(icp_set)} × {icp_templates} templates "
        f"{icp_s:.1f} s")
    return {"category": category, "mode": mode, "n": len(samples), "rows": rows, "_errors": errors,
            "_info": {"scale": scale, "symmetry": symmetry, "icp_templates": [int(i) for i in pick],
                      "icp_per_template": trows, "icp_samples": len(icp_set),
                      "seconds": {"ours": ours_s, "icp60": icp_s}}}


def format_table(result: dict) -> str:
    lines = [f"{result['category']} / {result['mode']}  (n = {result['n']})",
             f"{'method':10s} {'rot mean':>9s} {'rot med':>8s} {'t mean':>7s} {'t med':>7s} {'5°':>5s} "
             f"{'5°0.05':>7s} {'flip':>5s}"]
    n_icp = result.get("_info", {}).get("icp_samples", result["n"])
    for r in result["rows"]:
        name = r["method"] + (f" (n={n_icp})" if r["method"] == "icp60" and n_icp != result["n"] else "")
        name += f" ({r['fraction']:.0%} of views)" if "fraction" in r else ""
        lines.append(f"{name:10s} {r['rot_mean_deg']:9.2f} {r['rot_median_deg']:8.2f} {r['trans_mean']:7.3f} "
                     f"{r['trans_median']:7.3f} {r['acc_5deg']:5.2f} {r['acc_5deg_005']:7.2f} {r['flip_rate']:5.2f}")
    return "\n".join(lines)


def metrics_for_metadata(result: dict) -> dict:
    """The compact ``metrics`` metadata entry of a model: its own row, ICP-60's row, test-set description."""
    rows = {r["method"]: {k: round(float(r[k]), 4) for k in row_keys()[1:]} for r in result["rows"]}
    info = result.get("_info", {})
    ours = result["rows"][0]["method"]                                  # "equipose" or "equipose+icpK"
    subsets = {r["method"].split("[")[1].rstrip("]"): {**rows[r["method"]], "fraction": round(r["fraction"], 4)}
               for r in result["rows"] if "fraction" in r}                 # e.g. "handle seen" / "handle hidden"
    return {"test_set": f"{result['category']}/{result['mode']} test split (equipose.train.evaluation.evaluate)",
            "n": int(result["n"]), "icp60_samples": int(info.get("icp_samples", result["n"])),
            "method": ours, **rows[ours], "icp60": rows.get("icp60", {}), **subsets}


def write_json(result: dict, path) -> None:
    clean = {k: result[k] for k in ("category", "mode", "n", "rows")}
    pathlib.Path(path).parent.mkdir(parents=True, exist_ok=True)
    pathlib.Path(path).write_text(json.dumps(clean, indent=1) + "\n")


def plot_percentiles(result: dict, path) -> None:
    """PNG: rotation (and translation) error against percentile of test samples, one curve per method."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    q = np.linspace(0, 100, 201)
    for name, (r, t) in result["_errors"].items():
        axes[0].plot(q, np.maximum(np.percentile(r, q), 1e-2), label=name)
        axes[1].plot(q, np.percentile(t, q), label=name)
    axes[0].set_ylabel("rotation error (°)")
    axes[1].set_ylabel("translation error (/ bbox diagonal)")
    for ax in axes:
        ax.set_xlabel("percentile of test samples")
        ax.grid(alpha=0.3)
        ax.legend()
    axes[0].set_yscale("log")
    fig.suptitle(f"{result['category']} / {result['mode']} (n = {result['n']})")
    fig.tight_layout()
    pathlib.Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
