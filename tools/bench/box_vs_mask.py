"""Box prompt against the object's own mask on the labelled real Kinect scenes of mOSD: does a detector's box give
the pose the mask gives?

Usage: python tools/bench/box_vs_mask.py [--models can-tabletop cup-tabletop bowl-tabletop] [--data DIR]
    [--profile default] [--up none|plane] [--stages JSON] [--json FILE]
For every labelled object (``label // 10``, labels ≥ 20) of every ``learn*.pcd``: ``predict(mask=its pixels)`` and
``predict(box=the mask's bounding box)`` with the same estimator; prints per model the angle between the two poses'
axes (symmetry axis, or the rotation's z column), the distance between their centres, the share of objects whose box
pose is > 10° or > 2 cm off the mask pose, and how many box crops reported something in front (``occlusion``).
Angles in degrees (sign-folded: an axis and its negative are the same), distances in millimetres. ``--up``: the up
prior of both predictions (default none, which compares the two crops alone; "plane": the frame's support plane).
``--stages``: stage options for both (``PoseEstimator(stages=...)``, e.g. '{"axis_centre": {"enabled": true}}').
A second table keeps, per model, only the objects of its own category (``--assign``, default
docs/results/real/mosd_categories.json: cup, bowl, can → cup-, bowl-, can-tabletop), with the shares beyond the
2° and 5 mm a box is held to against the mask.
The centre distance is also split into its part along the support plane's normal (the object's height; the plane of
a mask prompt with ``up="plane"``) and across it.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import sys

import numpy as np

from equipose import PoseEstimator
from equipose.core.errors import EquiposeError
from equipose.eval.real_axes import CATEGORY_MODELS, DEFAULT_ASSIGN
from equipose.sources.pcd import read_organized_cloud


def _axis(r) -> np.ndarray:
    return r.symmetry_axis if r.symmetry_axis is not None else r.rotation[:, 2]


def objects(cloud: dict, min_pixels: int = 200) -> list:
    """[(object id, mask [H, W] bool, box (x, y, w, h))] of an mOSD cloud's labelled objects."""
    label = cloud["fields"]["label"].astype(np.int64)
    out = []
    for oid in sorted(set((label[label >= 20] // 10).tolist())):
        mask = (label // 10 == oid) & (label >= 20) & (cloud["depth"] > 0)
        if mask.sum() < min_pixels:
            continue
        rows, cols = np.nonzero(mask)
        out.append((oid, mask, (int(cols.min()), int(rows.min()), int(np.ptp(cols)) + 1, int(np.ptp(rows)) + 1)))
    return out


def scene_arguments(description: str) -> argparse.ArgumentParser:
    """The arguments the mOSD scene tools share: --models, --data (default ../shared/data or $EQUIPOSE_DATA),
    --profile, --json."""
    root = pathlib.Path(os.environ.get("EQUIPOSE_DATA", pathlib.Path(__file__).resolve().parents[2].parent
                                        / "shared" / "data"))
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("--models", nargs="+", default=["can-tabletop", "cup-tabletop", "bowl-tabletop"])
    ap.add_argument("--data", default=str(root / "kinect_pcl_objects" / "mOSD_learn_cylindric"))
    ap.add_argument("--profile", default="default")
    ap.add_argument("--json", help="write per-object rows here")
    return ap


def read_scenes(folder) -> dict:
    """{scene name: organized cloud} of the ``learn*.pcd`` files under ``folder``; exits with status 1 when there are
    none."""
    clouds = {p.stem: read_organized_cloud(p) for p in sorted(pathlib.Path(folder).glob("learn*.pcd"))}
    if not clouds:
        print(f"no learn*.pcd under {folder}", file=sys.stderr)
        raise SystemExit(1)
    return clouds


def main(argv=None) -> int:
    ap = scene_arguments(__doc__.splitlines()[0])
    ap.add_argument("--up", choices=("none", "plane"), default="none", help="the up prior of both predictions")
    ap.add_argument("--stages", type=json.loads, default=None, help="stage options of both predictions, as JSON")
    ap.add_argument("--assign", default=str(DEFAULT_ASSIGN), help="the objects' categories (for the own-category table)")
    a = ap.parse_args(argv)
    clouds = read_scenes(a.data)
    rows = []
    for model in a.models:
        try:
            est = PoseEstimator(model, profile=a.profile, stages=a.stages)
        except TypeError:                                                       # an SDK without profiles
            est = PoseEstimator(model)
        for name, cloud in clouds.items():
            for oid, mask, box in objects(cloud):
                try:
                    up = None if a.up == "none" else a.up
                    rm = est.predict(cloud["depth"], cloud["K"], mask=mask, up=up)
                    rb = est.predict(cloud["depth"], cloud["K"], box=box, up=up)
                    rp = rm if up == "plane" else est.predict(cloud["depth"], cloud["K"], mask=mask, up="plane")
                except EquiposeError as e:
                    rows.append({"model": model, "scene": name, "object": oid, "error": type(e).__name__})
                    continue
                c = float(np.clip(abs(_axis(rm) @ _axis(rb)), 0.0, 1.0))
                d = rb.translation - rm.translation                                 # [3] m, camera frame
                normal = rp.up if rp.up is not None else _axis(rm)                  # the support plane's normal
                rows.append({"model": model, "scene": name, "object": oid, "axis_deg": float(np.degrees(np.arccos(c))),
                             "centre_mm": float(np.linalg.norm(d) * 1e3),
                             "height_mm": float(abs(d @ normal) * 1e3),
                             "across_mm": float(np.linalg.norm(d - (d @ normal) * normal) * 1e3),
                             "occlusion": getattr(rb, "occlusion", None)})
    print(f"{'model':16s} {'objects':>7s} {'axis° med':>9s} {'>10°':>6s} {'centre mm med':>13s} {'height':>6s} "
          f"{'across':>6s} {'>2 cm':>6s} {'occluded':>8s} {'errors':>6s}")
    for model in a.models:
        ok = [r for r in rows if r["model"] == model and "axis_deg" in r]
        err = sum(1 for r in rows if r["model"] == model and "error" in r)
        ax, ce = np.array([r["axis_deg"] for r in ok]), np.array([r["centre_mm"] for r in ok])
        occ = sum(1 for r in ok if (r["occlusion"] or 0) > 0)
        hi, ac = np.median([r["height_mm"] for r in ok]), np.median([r["across_mm"] for r in ok])
        print(f"{model:16s} {len(ok):7d} {np.median(ax):9.2f} {np.mean(ax > 10):6.2f} {np.median(ce):13.1f} {hi:6.1f} "
              f"{ac:6.1f} {np.mean(ce > 20):6.2f} {occ:8d} {err:6d}")
    own_table(rows, a.models, json.loads(pathlib.Path(a.assign).read_text()))
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


def own_table(rows: list, models, assign: dict) -> None:
    """Print, per model, the box-vs-mask figures on the objects ``assign`` ({scene: {object id: category}}) gives its
    category: medians, the largest axis angle, and the shares beyond 2° and 5 mm."""
    print(f"\nown category only (--assign): {'model':16s} {'objects':>7s} {'axis° med':>9s} {'max':>6s} {'>2°':>5s} "
          f"{'centre mm med':>13s} {'>5 mm':>6s}")
    for model in models:
        stem = pathlib.Path(model).name.removesuffix(".onnx").removesuffix(".int8")      # a name or a file of it
        cat = next((c for c, m in CATEGORY_MODELS.items() if m == stem), None)
        ok = [r for r in rows if r["model"] == model and "axis_deg" in r
              and cat is not None and assign.get(r["scene"], {}).get(str(r["object"])) == cat]
        if not ok:
            continue
        ax, ce = np.array([r["axis_deg"] for r in ok]), np.array([r["centre_mm"] for r in ok])
        print(f"{'':30s}{model:16s} {len(ok):7d} {np.median(ax):9.2f} {ax.max():6.1f} {np.mean(ax > 2):5.2f} "
              f"{np.median(ce):13.1f} {np.mean(ce > 5):6.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
