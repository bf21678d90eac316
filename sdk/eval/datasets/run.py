"""``equipose eval --dataset``: pose errors of exported models (through ``equipose.PoseEstimator``) on annotated real
RGB-D frames (YCB-Video, BOP, GraspNet), per object and prompt, with JSON rows and overlay JPEGs.

Convention:
    Camera frame OpenCV, metres. Each mapped object's ground truth becomes a category pose (``mapping``): rotation
    ``R_cat`` and origin ``c_cam``; the SDK's ``PoseResult.rotation`` / ``.translation`` estimate them.
    ``rot_err_deg``: ``equipose.eval.metrics.rotation_errors`` with the object's symmetry (continuous:z → the angle
    between the z axes, folded for ``unsigned_axis``; none → geodesic). ``axis_err_deg``: angle between the predicted
    and true category z (up / symmetry) axes (folded for ``unsigned_axis``). ``centre_err_mm``: ‖t̂ − c_cam‖ in mm.
    ``acc_5_5`` / ``acc_10_5``: rot_err ≤ 5° / 10° and centre_err ≤ 50 mm. ``ms``: the result's ``timings["total"]``
    (one object per call). Prompts: "mask" (the dataset's visible mask), "box" (that mask's tight box), "auto" (the
    SDK's own tabletop segmentation, ``predict_auto``, no ground truth used; each ground-truth object takes the nearest
    unclaimed detection whose points' centre lies within ``AUTO_MATCH_M`` of its true origin).
    A row is one (frame, object, prompt): ``status`` "ok", "skipped" (no category / model / mask: ``reason``) or
    "failed" (the SDK raised a typed error: ``reason``).
"""
from __future__ import annotations

import json
import pathlib
import time

import numpy as np

from equipose.core.errors import ConfigError, EquiposeError
from equipose.core.geometry import axis_angle_deg
from equipose.eval.datasets import bop, graspnet, ycbv
from equipose.eval.datasets.frames import mask_box
from equipose.eval.datasets.mapping import DEFAULT_MAPPING, load_mapping
from equipose.eval.metrics import rotation_errors

__all__ = ["parse_dataset", "open_frames", "evaluate_dataset", "format_table", "write_json", "PROMPTS", "AUTO_MATCH_M",
           "score_pose"]

READERS = {"ycbv": ycbv.scan, "bop": bop.scan, "graspnet": graspnet.scan}
PROMPTS = ("box", "mask", "auto")
PROMPT_SETS = {"box": ("box",), "mask": ("mask",), "auto": ("auto",), "both": ("box", "mask"),
               "all": ("box", "mask", "auto")}
AUTO_MATCH_M = 0.05
OVERLAY_WIDTH = 640


def parse_dataset(spec: str) -> tuple:
    """``"ycbv:DIR" | "bop:DIR" | "graspnet:DIR"`` → (kind, pathlib.Path). Raises ``ConfigError``."""
    kind, sep, path = str(spec).partition(":")
    if not sep or kind not in READERS or not path:
        raise ConfigError(f"--dataset must be KIND:DIR with KIND one of {sorted(READERS)}, got {spec!r}")
    return kind, pathlib.Path(path)


def open_frames(spec: str, limit: int | None = None) -> tuple:
    """(kind, [(frame_id, loader)]) of a dataset spec, the first ``limit`` frames if given. Raises ``SourceError``
    (no such layout) or ``ConfigError`` (bad spec / limit)."""
    kind, path = parse_dataset(spec)
    if limit is not None and limit < 1:
        raise ConfigError(f"--limit must be ≥ 1, got {limit}")
    frames = READERS[kind](path)
    return kind, frames[:limit] if limit else frames


def score_pose(R_pred, t_pred, R_cat, c_cam, entry) -> dict:
    """Errors of one predicted category pose against the ground truth.

    Convention: ``R_pred``, ``R_cat`` [3, 3] category → camera; ``t_pred``, ``c_cam`` [3] metres; ``entry`` an
    ``ObjectEntry`` (symmetry, unsigned_axis). Returns {rot_err_deg, axis_err_deg, centre_err_mm, acc_5_5, acc_10_5}.
    """
    R_pred, R_cat = np.asarray(R_pred, np.float64), np.asarray(R_cat, np.float64)
    t_pred, c_cam = np.asarray(t_pred, np.float64), np.asarray(c_cam, np.float64)
    if R_pred.shape != (3, 3) or R_cat.shape != (3, 3) or t_pred.shape != (3,) or c_cam.shape != (3,):
        raise ConfigError(f"score_pose needs two [3, 3] rotations and two [3] points, got {R_pred.shape}, "
                          f"{R_cat.shape}, {t_pred.shape}, {c_cam.shape}")
    rot = float(rotation_errors(R_pred[None], R_cat[None], entry.symmetry, entry.unsigned_axis)[0])
    axis = float(axis_angle_deg(R_pred[:, 2], R_cat[:, 2], unsigned=entry.unsigned_axis))
    cen = float(np.linalg.norm(t_pred - c_cam) * 1000.0)
    return {"rot_err_deg": round(rot, 3), "axis_err_deg": round(axis, 3), "centre_err_mm": round(cen, 2),
            "acc_5_5": bool(rot <= 5.0 and cen <= 50.0), "acc_10_5": bool(rot <= 10.0 and cen <= 50.0)}


def _load_models(models, profile: str) -> dict:
    """{category: PoseEstimator} for model names / paths; two models of one category → ``ConfigError``."""
    from equipose.runtime.estimator import PoseEstimator
    out = {}
    for m in models:
        est = PoseEstimator(m, profile=profile)
        if est.category in out:
            raise ConfigError(f"two models for category {est.category!r} ({out[est.category].path.name}, "
                              f"{est.path.name}); give one per category")
        out[est.category] = est
    return out


def _result_fields(res) -> dict:
    occ = res.occlusion
    return {"confidence": round(float(res.confidence), 4), "ambiguous": bool(res.ambiguous),
            "occlusion": None if occ is None else round(occ, 4), "ms": round(float(res.timings.get("total", 0.0)), 2),
            "num_points": int(res.num_points), "handle_visible": res.handle_visible,
            "rotation": np.round(res.rotation, 6).tolist(), "translation_m": np.round(res.translation, 5).tolist()}


def _up_arg(up: str | None, R_cat):
    if up == "gt":
        return R_cat[:, 2]
    return "plane" if up == "plane" else None


def _auto_matches(est, frame, todo, up) -> dict:
    """{object index: PoseResult | str} — each object takes the nearest unclaimed auto detection within AUTO_MATCH_M."""
    t0 = time.perf_counter()
    dets = est.predict_auto(frame.depth_m, frame.K, depth_unit="m", return_errors=True,
                            up=None if up == "gt" else up)
    dets = [d for d in dets if getattr(d, "points_centre", None) is not None]
    pairs = sorted((float(np.linalg.norm(d.points_centre - c)), i, j)
                   for i, (_, _, _, c) in todo.items() for j, d in enumerate(dets))
    out, used = {}, set()
    for dist, i, j in pairs:
        if i in out or j in used or dist > AUTO_MATCH_M:
            continue
        out[i] = dets[j]
        used.add(j)
    for i in todo:
        out.setdefault(i, f"auto: no detection of the {est.category} model within {AUTO_MATCH_M * 100:.0f} cm "
                          f"({len(dets)} found in {(time.perf_counter() - t0) * 1e3:.0f} ms)")
    return out


def evaluate_dataset(spec: str, models, *, objects=None, prompt: str = "both", limit: int | None = None,
                     profile: str = "default", up: str | None = None, mapping=None, overlays=None,
                     progress: bool = True) -> dict:
    """Evaluate ``models`` (names or .onnx paths, one per category) on every mapped object of a dataset.

    Convention: ``spec`` "KIND:DIR"; ``objects`` None or names / ids to keep; ``prompt`` box | mask | auto | both |
    all; ``up`` None | "none" | "plane" | "gt" (the true category z as the up prior); ``mapping`` a TOML path (default:
    the dataset's shipped one); ``overlays`` a folder for one JPEG per frame and prompt (≤ 640 px wide). Returns
    {"dataset", "models", "prompts", "rows": [row], "summary": [per object and prompt, then "ALL" per prompt]};
    rows and errors as in the module docstring. Raises ``ConfigError`` / ``SourceError`` for bad arguments or files.
    """
    if prompt not in PROMPT_SETS:
        raise ConfigError(f"--prompt must be one of {sorted(PROMPT_SETS)}, got {prompt!r}")
    if up not in (None, "none", "plane", "gt"):
        raise ConfigError(f"--up must be plane, none or gt, got {up!r}")
    up = None if up == "none" else up
    prompts = PROMPT_SETS[prompt]
    if isinstance(models, str):
        models = [m for m in models.split(",") if m]
    if not models:
        raise ConfigError("give at least one model (--model NAME[,NAME...] or .onnx paths)")
    kind, frames = open_frames(spec, limit)
    table = load_mapping(mapping or kind)
    keep = None if not objects else {str(o) for o in objects}
    ests = _load_models(models, profile)
    out_dir = None if overlays is None else pathlib.Path(overlays)
    if out_dir is not None:
        out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    it = frames
    if progress:
        try:
            from tqdm import tqdm
            it = tqdm(frames, desc=f"eval {kind}", unit="frame")
        except ModuleNotFoundError:                                             # tqdm is optional for the SDK
            pass
    for fid, loader in it:
        frame = loader()
        drawn = {p: [] for p in prompts}                                        # prompt → [(result, R_cat, c_cam)]
        todo = {}                                                               # category → {index: (obj, entry, R, c)}
        for obj in frame.objects:
            entry = table.get(obj.key)
            name = entry.name if entry else f"id {obj.key}"
            if keep is not None and name not in keep and str(obj.key) not in keep:
                continue
            base = {"frame": fid, "object_key": obj.key, "object": name, "index": obj.index}
            reason = (f"id {obj.key} is not in the {kind} mapping" if entry is None else
                      entry.skip_reason if entry.category is None else
                      f"no model for category {entry.category!r} (add --model {entry.model})"
                      if entry.category not in ests else None)
            if reason:
                rows += [{**base, "prompt": p, "status": "skipped", "reason": reason} for p in prompts]
                continue
            R_cat, c_cam = entry.category_pose(obj.R, obj.t)
            base.update(category=entry.category, model=ests[entry.category].path.name)
            todo.setdefault(entry.category, {})[obj.index] = (obj, entry, R_cat, c_cam)
        for cat, objs in todo.items():
            est = ests[cat]
            auto = _auto_matches(est, frame, objs, up) if "auto" in prompts else {}
            for i, (obj, entry, R_cat, c_cam) in objs.items():
                base = {"frame": fid, "object_key": obj.key, "object": entry.name, "index": obj.index,
                        "category": cat, "model": est.path.name}
                for p in prompts:
                    row = {**base, "prompt": p}
                    res, why = None, None
                    if p == "auto":
                        res = auto[i] if not isinstance(auto[i], str) else None
                        why = auto[i] if isinstance(auto[i], str) else None
                        if res is not None and not hasattr(res, "rotation"):              # a FrameError
                            res, why = None, f"auto: {getattr(res, 'message', res)}"
                    elif obj.mask is None:
                        why = obj.missing
                    elif not obj.mask.any():
                        why = "empty mask: the object is not visible in this frame"
                    else:
                        region = {"mask": obj.mask} if p == "mask" else {"box": mask_box(obj.mask)}
                        try:
                            res = est.predict(frame.depth_m, frame.K, depth_unit="m", up=_up_arg(up, R_cat), **region)
                        except EquiposeError as e:
                            rows.append({**row, "status": "failed", "reason": f"{type(e).__name__}: {e}"})
                            continue
                    if res is None:
                        rows.append({**row, "status": "skipped", "reason": why})
                        continue
                    rows.append({**row, "status": "ok", **score_pose(res.rotation, res.translation, R_cat, c_cam,
                                                                     entry), **_result_fields(res)})
                    drawn[p].append((res, R_cat, c_cam))
        if out_dir is not None:
            for p in (p for p in prompts if drawn[p]):                        # frames with a pose to show
                _write_overlay(out_dir / f"{fid.replace('/', '_')}_{p}.jpg", frame, drawn[p])
    return {"dataset": spec, "models": [e.path.name for e in ests.values()], "profile": profile, "up": up,
            "prompts": list(prompts), "rows": rows, "summary": summarize_rows(rows)}


def summarize_rows(rows: list) -> list:
    """Per (object, prompt) then per prompt ("ALL"): n, skipped, failed, medians (rot, axis, centre mm), accuracies,
    mean confidence and ms. Convention: ``rows`` as ``evaluate_dataset`` returns them."""
    groups = {}
    for r in rows:
        for key in ((r["object"], r["prompt"]), ("ALL", r["prompt"])):
            groups.setdefault(key, []).append(r)
    out = []
    order = sorted(groups, key=lambda k: (k[0] == "ALL", k[0], k[1]))
    for obj, p in order:
        g = groups[(obj, p)]
        ok = [r for r in g if r["status"] == "ok"]
        s = {"object": obj, "prompt": p, "n": len(ok), "skipped": sum(r["status"] == "skipped" for r in g),
             "failed": sum(r["status"] == "failed" for r in g)}
        if ok:
            f = lambda k: np.array([r[k] for r in ok], np.float64)             # noqa: E731
            s.update(rot_med_deg=round(float(np.median(f("rot_err_deg"))), 2),
                     axis_med_deg=round(float(np.median(f("axis_err_deg"))), 2),
                     centre_med_mm=round(float(np.median(f("centre_err_mm"))), 1),
                     acc_5_5=round(float(f("acc_5_5").mean()), 3), acc_10_5=round(float(f("acc_10_5").mean()), 3),
                     confidence_mean=round(float(f("confidence").mean()), 3),
                     ambiguous_rate=round(float(f("ambiguous").mean()), 3), ms_mean=round(float(f("ms").mean()), 1))
        out.append(s)
    return out


def format_table(res: dict) -> str:
    """The summary as a Markdown table, then one line per distinct skip / failure reason."""
    head = ("| object | prompt | n | rot med ° | axis med ° | centre med mm | 5°5cm | 10°5cm | conf | ambig | ms | "
            "skipped | failed |")
    lines = [head, "|" + "---|" * 13]
    for s in res["summary"]:
        g = lambda k, spec: "-" if k not in s else format(s[k], spec)          # noqa: E731
        lines.append(f"| {s['object']} | {s['prompt']} | {s['n']} | {g('rot_med_deg', '.1f')} | "
                     f"{g('axis_med_deg', '.1f')} | {g('centre_med_mm', '.1f')} | {g('acc_5_5', '.2f')} | "
                     f"{g('acc_10_5', '.2f')} | {g('confidence_mean', '.2f')} | {g('ambiguous_rate', '.2f')} | "
                     f"{g('ms_mean', '.0f')} | {s['skipped']} | {s['failed']} |")
    reasons = {}
    for r in res["rows"]:
        if r["status"] != "ok":
            reasons.setdefault((r["object"], r["status"], r["reason"]), 0)
            reasons[(r["object"], r["status"], r["reason"])] += 1
    if reasons:
        lines.append("")
        lines += [f"- {obj}: {st} ×{n}: {why}" for (obj, st, why), n in sorted(reasons.items())]
    return "\n".join(lines)


def write_json(res: dict, path) -> None:
    """``res`` as indented JSON at ``path`` (parent folders created)."""
    p = pathlib.Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(res, indent=1))


def _write_overlay(path: pathlib.Path, frame, drawn: list) -> None:
    """Predicted poses (the SDK's ``draw_poses``) and the ground-truth category axes (thin, 5 cm: x pink, y lime, z
    cyan) on the colour image (or the colourised depth), scaled to ≤ 640 px wide, JPEG quality 70."""
    import cv2
    from equipose.runtime.overlay import draw_poses, project
    img = frame.rgb if frame.rgb is not None else frame.depth_m
    img = draw_poses(img, frame.K, [d[0] for d in drawn], legend=False)
    for _, R_cat, c in drawn:
        pts = np.vstack([c, c + 0.05 * R_cat.T])                               # origin + 3 axis tips [4, 3]
        uv, front = project(pts, frame.K)
        if front.all():
            o = tuple(int(round(v)) for v in uv[0])
            for k, col in enumerate(((203, 102, 255), (0, 255, 160), (255, 255, 0))):
                cv2.line(img, o, tuple(int(round(v)) for v in uv[k + 1]), col, 1, cv2.LINE_AA)
    h, w = img.shape[:2]
    if w > OVERLAY_WIDTH:
        img = cv2.resize(img, (OVERLAY_WIDTH, int(round(h * OVERLAY_WIDTH / w))), interpolation=cv2.INTER_AREA)
    cv2.imwrite(str(path), img, [cv2.IMWRITE_JPEG_QUALITY, 70])
