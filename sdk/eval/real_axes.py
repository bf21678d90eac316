"""Real-data check of predicted symmetry axes against the table normal on the labelled Kinect scenes of mOSD.

Usage:
    python tools/bench/eval_real_axes.py [--models cup-tabletop bowl-tabletop can-tabletop] [--data DIR]
        [--json docs/results/real/mosd_axes.json] [--overlays docs/results/real/overlays | --no-overlays]
        [--limit-scenes K] [--threads 1] [--min-points 64] [--overlay-width 480]

For each scene ``learn*.pcd`` of ``--data`` (default ``$EQUIPOSE_DATA/kinect_pcl_objects/mOSD_learn_cylindric``,
``$EQUIPOSE_DATA`` defaulting to ``../shared/data`` beside the repository): fit the table plane (labels 1–9, RANSAC +
least squares, normal oriented towards the camera), group the object points (object id = label // 10, label ≥ 20;
objects with fewer than ``--min-points`` valid points are skipped and listed), run every model through
``PoseEstimator.predict_points`` on each object's points and compare its axis with the table normal: the model's
``symmetry_axis``, or the rotation's z column when the model's symmetry is "none" (the output says which). The same
comparison for a trivial baseline, the principal (largest-variance) axis of the object's points, is reported next to it.

Convention:
    Camera frame OpenCV (x right, y down, z forward), metres. Angles in degrees: ``a`` ∈ [0, 90] is the sign-folded
    angle between axis and table normal; ``deviation`` = min(a, 90 − a) (a resting cylinder is upright or lying);
    "upright" when a ≤ 45, else "lying". Summaries: median and max deviation, fraction of objects within 10° and 20°.
    Timings are wall seconds per scene (reading, plane fit, all models, overlays). The summary's ``random-axis`` row
    is the chance level of an axis uniform on the sphere (median 24.3°, 19 % within 10°, 40 % within 20°): the folded
    deviation also rewards any horizontal axis, so a model must beat this row, not 45°, to show skill.

Outputs: a table on stdout, a JSON file (per-object rows, per-model summaries, per-scene table fits), and one PNG
overlay per scene and model (``<scene>_<model>.png``: colour image, pose boxes/axes, the evaluated axis as a magenta
±6 cm line through each predicted origin, the table normal as a yellow 10 cm arrow at the table centroid, and per
object "#id <deviation><U|L>  pca <baseline deviation>" (U upright, L lying); pixels outside the cloud are dark grey and colours are posterized to 32
levels to keep the PNGs small).
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys
import time

import numpy as np

from equipose.core.errors import EquiposeError, ModelFormatError, SourceError
from equipose.eval.real_axes_overlay import draw_overlay
from equipose.eval.realdata import (axis_table_angle, group_objects, load_labelled_scene, principal_axis,
                                    random_axis_summary, summarize_deviations, table_plane)

ROOT = pathlib.Path(__file__).resolve().parents[2]          # the repository (editable install)
DEFAULT_DATA = pathlib.Path(os.environ.get("EQUIPOSE_DATA", ROOT.parent / "shared" / "data")) / \
    "kinect_pcl_objects" / "mOSD_learn_cylindric"
DEFAULT_MODELS = ["cup-tabletop", "bowl-tabletop", "can-tabletop"]
CATEGORY_MODELS = {"cup": "cup-tabletop", "bowl": "bowl-tabletop", "can": "can-tabletop"}   # mOSD category → model
DEFAULT_ASSIGN = ROOT / "docs" / "results" / "real" / "mosd_categories.json"   # {scene: {object id: category}}
BASELINE = "pca-baseline"
CHANCE = "random-axis"


def _scene_key(p: pathlib.Path):
    digits = "".join(ch for ch in p.stem if ch.isdigit())
    return (int(digits) if digits else -1, p.stem)


def find_scenes(data: pathlib.Path, limit: int | None) -> list:
    """Sorted ``learn*.pcd`` (or any ``*.pcd``) of ``data``; raises ``SourceError`` when none."""
    if not data.is_dir():
        raise SourceError(f"data folder {data} does not exist; pass --data (the mOSD_learn_cylindric folder) "
                          "or set EQUIPOSE_DATA")
    paths = sorted(data.glob("learn*.pcd"), key=_scene_key) or sorted(data.glob("*.pcd"), key=_scene_key)
    if not paths:
        raise SourceError(f"no .pcd files in {data}")
    return paths[:limit] if limit else paths


def load_models(names: list, threads: int) -> list:
    """[(label, PoseEstimator, axis source)] — every name resolved first; raises ``ModelFormatError``."""
    from equipose.runtime.estimator import PoseEstimator
    from equipose.runtime.hypotheses import parse_symmetry
    from equipose.models import resolve_model
    paths = [(str(n), resolve_model(n)) for n in names]                          # fail before any work
    out = []
    for name, path in paths:
        label = pathlib.Path(name).stem if ("/" in name or name.endswith(".onnx")) else name
        est = PoseEstimator(path, threads=threads)
        kind, axis, _ = parse_symmetry(est.symmetry)
        source = (f"symmetry_axis (rotation column {'xyz'[axis]}, {est.symmetry})" if kind != "none"
                  else "rotation[:, 2] (model symmetry is 'none': its z column stands in for the axis)")
        out.append((label, est, source))
    return out


def _fmt(x, spec=".1f", none="-"):
    return none if x is None else format(x, spec)


def evaluate_scene(path, models, *, min_points: int, overlay_dir, overlay_width: int) -> tuple:
    """One scene → (scene summary dict, object rows). Per-object model errors are recorded, not raised."""
    t0 = time.perf_counter()
    scene = load_labelled_scene(path)
    plane = table_plane(scene)
    objects, skipped = group_objects(scene.label, scene.valid, min_points=min_points)
    rows, per_model = [], {label: [] for label, _, _ in models}
    for oid, mask in objects.items():
        pts = scene.xyz[mask].astype(np.float64)                                # [P, 3] m, camera frame
        base = axis_table_angle(principal_axis(pts), plane.normal)
        for label, est, source in models:
            row = {"scene": scene.name, "object_id": oid, "num_points": int(len(pts)), "model": label,
                   "centroid_m": np.round(pts.mean(axis=0), 4).tolist(),
                   "baseline_angle": base.angle, "baseline_deviation": base.deviation, "baseline_pose": base.pose}
            try:
                res = est.predict_points(pts)
            except EquiposeError as e:
                row.update(error=f"{type(e).__name__}: {e}", angle=None, deviation=None, pose=None, confidence=None)
                rows.append(row)
                per_model[label].append((oid, None, row))
                continue
            res.object_id = oid
            axis = res.symmetry_axis if res.symmetry_axis is not None else res.rotation[:, 2]
            ang = axis_table_angle(axis, plane.normal)
            row.update(angle=ang.angle, deviation=ang.deviation, pose=ang.pose, confidence=float(res.confidence),
                       ambiguous=bool(res.ambiguous), axis_source="symmetry_axis" if res.symmetry_axis is not None
                       else "rotation_z", axis=np.round(axis, 6).tolist(), random_init=bool(res.random_init),
                       pose_result=res.to_dict())
            rows.append(row)
            per_model[label].append((oid, res, row))
    overlays = []
    if overlay_dir is not None:
        import cv2
        for label, est, _ in models:
            img = draw_overlay(scene, plane, per_model[label], label, est.random_init, overlay_width)
            out = pathlib.Path(overlay_dir) / f"{scene.name}_{label}.png"
            cv2.imwrite(str(out), img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
            overlays.append(str(out))
    table = scene.valid & (scene.label >= 1) & (scene.label <= 9)
    info = {"scene": scene.name, "path": str(path), "num_objects": len(objects),
            "skipped_objects": {str(k): v for k, v in skipped.items()},
            "table": {"normal": np.round(plane.normal, 6).tolist(), "centroid_m": np.round(plane.centroid, 4).tolist(),
                      "num_points": int(table.sum()), "inlier_fraction": float(plane.inliers.mean()),
                      "rms_m": plane.rms},
            "K": np.round(scene.K, 3).tolist(), "has_colour": scene.rgb is not None, "overlays": overlays,
            "seconds": time.perf_counter() - t0}
    return info, rows


def print_rows(rows: list):
    hdr = (f"{'scene':<9} {'obj':>3} {'points':>6} {'model':<16} {'a°':>5} {'dev°':>5} {'pose':<7} {'conf':>5}   "
           f"{'pca a°':>6} {'pca dev°':>8} {'pca pose':<8}")
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        tail = f"  {r['error']}" if r.get("error") else ""
        print(f"{r['scene']:<9} {r['object_id']:>3} {r['num_points']:>6} {r['model']:<16} {_fmt(r['angle']):>5} "
              f"{_fmt(r['deviation']):>5} {r['pose'] or '-':<7} {_fmt(r['confidence'], '.2f'):>5}   "
              f"{r['baseline_angle']:>6.1f} {r['baseline_deviation']:>8.1f} {r['baseline_pose']:<8}{tail}")


def summarize(rows: list, model_labels: list) -> dict:
    out = {}
    for label in model_labels:
        mine = [r for r in rows if r["model"] == label]
        s = summarize_deviations([r["deviation"] for r in mine])
        s["errors"] = sum(1 for r in mine if r.get("error"))
        s["median_angle"] = (float(np.median([r["angle"] for r in mine if r["angle"] is not None]))
                             if s["n"] else None)
        out[label] = s
    first = {}
    for r in rows:                                                              # baseline: once per object
        first.setdefault((r["scene"], r["object_id"]), r)
    s = summarize_deviations([r["baseline_deviation"] for r in first.values()])
    s["errors"] = 0
    s["median_angle"] = float(np.median([r["baseline_angle"] for r in first.values()])) if first else None
    out[BASELINE] = s
    s = random_axis_summary()                                                   # analytic, uniform axis on the sphere
    s["errors"], s["median_angle"] = 0, 60.0
    out[CHANCE] = s
    return out


def with_matched_summary(summary: dict, rows: list) -> dict:
    """``summary`` with a leading ``matched`` entry (each object judged by its category's model), when any row is
    matched. Convention: deviations and rest-pose errors in degrees (see the module docstring)."""
    matched = [r for r in rows if r["matched"]]
    if matched:                                                                 # each object by its category's model
        s = summarize_deviations([r["deviation"] for r in matched])
        s["errors"] = sum(1 for r in matched if r.get("error"))
        s["median_angle"] = float(np.median([r["angle"] for r in matched if r["angle"] is not None]))
        s["per_category"] = {c: summarize_deviations([r["deviation"] for r in matched if r["category"] == c])
                             for c in sorted({r["category"] for r in matched})}
        s["rest_pose_error"] = summarize_deviations([r.get("rest_pose_error") for r in matched])
        s["baseline_rest_pose_error"] = summarize_deviations([r.get("baseline_rest_pose_error") for r in matched])
        summary = {"matched": s, **summary}
        base = {}
        for r in rows:
            if r["category"] is not None:
                base.setdefault((r["scene"], r["object_id"]), r)
        summary["matched"]["baseline_per_category"] = {
            c: summarize_deviations([r["baseline_deviation"] for r in base.values() if r["category"] == c])
            for c in sorted({r["category"] for r in base.values()})}
    return summary


def print_summary(summary: dict):
    print(f"\n{'model':<16} {'objects':>7} {'median dev°':>11} {'worst dev°':>10} {'≤10°':>6} {'≤20°':>6} "
          f"{'median a°':>9} {'errors':>6}")
    for label, s in summary.items():
        print(f"{label:<16} {_fmt(s['n'], 'd', 'chance'):>7} {_fmt(s['median']):>11} {_fmt(s['max']):>10} {_fmt(s['within_10'], '.2f'):>6} "
              f"{_fmt(s['within_20'], '.2f'):>6} {_fmt(s['median_angle']):>9} {s['errors']:>6}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", nargs="+", default=DEFAULT_MODELS, help="shipped model names or .onnx paths")
    ap.add_argument("--data", type=pathlib.Path, default=DEFAULT_DATA, help="folder of labelled mOSD .pcd scenes")
    ap.add_argument("--json", type=pathlib.Path, default=ROOT / "docs" / "results" / "real" / "mosd_axes.json")
    ap.add_argument("--overlays", type=pathlib.Path, default=ROOT / "docs" / "results" / "real" / "overlays")
    ap.add_argument("--no-overlays", action="store_true", help="do not write overlay PNGs")
    ap.add_argument("--overlay-width", type=int, default=480, help="overlay width in pixels (downscaled)")
    ap.add_argument("--limit-scenes", type=int, default=None, metavar="K", help="only the first K scenes")
    ap.add_argument("--threads", type=int, default=1, help="onnxruntime intra-op threads")
    ap.add_argument("--min-points", type=int, default=64, help="skip objects with fewer valid points")
    ap.add_argument("--assign", type=pathlib.Path, default=DEFAULT_ASSIGN,
                    help="JSON {scene: {object id: category}}: adds a 'matched' summary row where each object is "
                         "judged by the model of its category (see --category-models); '' to skip")
    ap.add_argument("--category-models", default=",".join(f"{c}={m}" for c, m in CATEGORY_MODELS.items()),
                    help="category=model label pairs for the matched row (default %(default)s)")
    args = ap.parse_args(argv)

    try:
        models = load_models(args.models, args.threads)
        scenes = find_scenes(args.data, args.limit_scenes)
    except (ModelFormatError, SourceError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for label, est, source in models:
        flag = "  ** RANDOM WEIGHTS: poses are meaningless **" if est.random_init else ""
        print(f"model {label}: {est!r}\n  axis: {source}{flag}")
    overlay_dir = None if args.no_overlays else args.overlays
    if overlay_dir is not None:
        overlay_dir.mkdir(parents=True, exist_ok=True)

    infos, rows = [], []
    for path in scenes:
        try:
            info, scene_rows = evaluate_scene(path, models, min_points=args.min_points, overlay_dir=overlay_dir,
                                              overlay_width=args.overlay_width)
        except EquiposeError as e:
            print(f"{path.name}: skipped ({type(e).__name__}: {e})", file=sys.stderr)
            infos.append({"scene": path.stem, "path": str(path), "error": f"{type(e).__name__}: {e}"})
            continue
        infos.append(info)
        rows.extend(scene_rows)
        sk = ", ".join(f"#{k} ({v} pts)" for k, v in info["skipped_objects"].items()) or "none"
        n = info["table"]["normal"]
        print(f"{info['scene']}: {info['num_objects']} objects, skipped {sk}; table normal "
              f"[{n[0]:+.3f} {n[1]:+.3f} {n[2]:+.3f}] rms {info['table']['rms_m'] * 1000:.1f} mm; "
              f"{info['seconds']:.2f} s")

    assign, lying = {}, {}
    if str(args.assign) and args.assign.is_file():
        doc_a = json.loads(args.assign.read_text())
        assign = {k: v for k, v in doc_a.items() if not k.startswith("_")}
        lying = doc_a.get("_lying", {})
    cat_models = dict(kv.split("=", 1) for kv in args.category_models.split(",") if "=" in kv)
    for r in rows:
        r["category"] = assign.get(r["scene"], {}).get(str(r["object_id"]))
        r["matched"] = r["category"] is not None and cat_models.get(r["category"]) == r["model"]
        if r["category"] is not None and r.get("angle") is not None:            # error against the known rest pose
            down = str(r["object_id"]) in lying.get(r["scene"], [])
            r["rest_pose"] = "lying" if down else "upright"
            r["rest_pose_error"] = 90.0 - r["angle"] if down else r["angle"]
            r["baseline_rest_pose_error"] = 90.0 - r["baseline_angle"] if down else r["baseline_angle"]
    print()
    print_rows(rows)
    summary = summarize(rows, [m[0] for m in models])
    summary = with_matched_summary(summary, rows)
    print_summary(summary)
    if "matched" in summary:
        m = summary["matched"]
        e, b = m["rest_pose_error"], m["baseline_rest_pose_error"]
        print(f"  matched, error against the known rest pose (upright/lying, not folded): median {_fmt(e['median'])}°, "
              f"worst {_fmt(e['max'])}°, ≤10° {_fmt(e['within_10'], '.2f')}, ≤20° {_fmt(e['within_20'], '.2f')}   "
              f"(pca baseline: median {_fmt(b['median'])}°, worst {_fmt(b['max'])}°)")
        for c, st in m["per_category"].items():
            b = m["baseline_per_category"].get(c, {})
            print(f"  matched {c:<5} n={st['n']:>2}  median {_fmt(st['median'])}°  worst {_fmt(st['max'])}°  "
                  f"≤10° {_fmt(st['within_10'], '.2f')}   (pca baseline: median {_fmt(b.get('median'))}°, worst "
                  f"{_fmt(b.get('max'))}°)")

    args.json.parent.mkdir(parents=True, exist_ok=True)
    doc = {"data": str(args.data), "convention": "camera frame OpenCV (x right, y down, z forward), metres; angles "
           "degrees; a = sign-folded angle axis vs table normal in [0, 90]; deviation = min(a, 90 - a)",
           "models": {label: {"path": str(est.path), "category": est.category, "symmetry": est.symmetry,
                              "random_init": est.random_init, "axis": source} for label, est, source in models},
           "scenes": infos, "rows": rows, "summary": summary}
    args.json.write_text(json.dumps(doc, indent=1))
    print(f"\nwrote {args.json}" + (f" and {sum(len(i.get('overlays', [])) for i in infos)} overlays in "
                                   f"{overlay_dir}" if overlay_dir is not None else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
