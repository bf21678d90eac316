"""Calibrated confidence on the labelled real Kinect scenes of mOSD (learn33–44), box and mask prompts, no up prior.

Usage: python tools/bench/real_confidence.py [--data DIR] [--assign mosd_categories.json] [--profile default]
    [--up none|plane] [--models-from DIR] [--json FILE]
Every labelled object that ``mosd_categories.json`` assigns to cup, bowl or can runs through its category's model
(``cup-tabletop``, ``bowl-tabletop``, ``can-tabletop``) twice: ``predict(mask=its pixels)`` and
``predict(box=the mask's bounding box)``, with ``up=None`` (``--up plane``: the up prior from the frame's support
plane). The scenes give no 6D ground truth, so the check is the
axis against the table (labels 1–9, its plane fitted by ``equipose.eval.realdata.table_plane``):
- ``tilt``: the signed angle between the result's axis (symmetry axis, else rotation z) and the table normal,
  0 = upright, 180 = upside down (a can's axis is unsigned, so its tilt is folded to 0–90);
- ``rest_err``: the error against the object's known rest pose: ``_lying`` objects lie (90°), ``_upside_down`` ones
  stand on their opening (180°), every other stands upright (0°); so an upright result counts 180° off on an
  upside-down cup, and the other way round.
Per model and prompt: objects, share with ``rest_err`` ≤ 10°, median confidence, the confidence's AUROC for
``rest_err`` ≤ 10° (how well it ranks the right axes above the wrong ones), and how many are *confident-wrong*
(``rest_err`` > 30°, confidence > 0.5, not ``ambiguous``). Angles in degrees.
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
from equipose.eval.datasets.frames import mask_box
from equipose.eval.metrics import auroc
from equipose.eval.real_axes import CATEGORY_MODELS, DEFAULT_ASSIGN
from equipose.eval.realdata import load_labelled_scene, table_plane

MODELS = CATEGORY_MODELS         # the model each mOSD category runs through


def _axis(r) -> np.ndarray:
    return r.symmetry_axis if r.symmetry_axis is not None else r.rotation[:, 2]


def main(argv=None) -> int:
    root = pathlib.Path(os.environ.get("EQUIPOSE_DATA", pathlib.Path(__file__).resolve().parents[2].parent
                                        / "shared" / "data"))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=str(root / "kinect_pcl_objects" / "mOSD_learn_cylindric"))
    ap.add_argument("--assign", default=str(DEFAULT_ASSIGN))
    ap.add_argument("--profile", default="default")
    ap.add_argument("--up", choices=("none", "plane"), default="none", help="the up prior of every prediction")
    ap.add_argument("--models-from", help="a folder of model files to use instead of the shipped ones of the same "
                                          "name (e.g. a re-fitted confidence)")
    ap.add_argument("--json", help="write per-object rows here")
    a = ap.parse_args(argv)
    assign = json.loads(pathlib.Path(a.assign).read_text())
    lying = assign.get("_lying", {})
    upside_down = assign.get("_upside_down", {})
    scenes = sorted(pathlib.Path(a.data).glob("learn*.pcd"))
    if not scenes:
        print(f"no learn*.pcd under {a.data}", file=sys.stderr)
        return 1
    def model(name: str) -> str:
        own = pathlib.Path(a.models_from or ".") / f"{name}.onnx"
        return str(own) if a.models_from and own.is_file() else name

    estimators = {cat: PoseEstimator(model(m), profile=a.profile) for cat, m in MODELS.items()}
    rows = []
    for path in scenes:
        scene = load_labelled_scene(path)
        normal = table_plane(scene).normal                                      # [3] camera frame, towards the camera
        label = scene.label.astype(np.int64)
        for oid, cat in assign.get(scene.name, {}).items():
            est = estimators.get(cat)
            mask = (label // 10 == int(oid)) & (label >= 20) & scene.valid
            if est is None or mask.sum() < 200:
                continue
            rest = 90.0 if oid in lying.get(scene.name, []) else 180.0 if oid in upside_down.get(scene.name, []) else 0.0
            for prompt, region in (("mask", {"mask": mask}), ("box", {"box": mask_box(mask)})):
                try:
                    r = est.predict(scene.depth, scene.K, depth_unit="mm", up=None if a.up == "none" else a.up, **region)
                except EquiposeError as e:
                    rows.append({"scene": scene.name, "object": oid, "category": cat, "prompt": prompt,
                                 "error": type(e).__name__})
                    continue
                ax = _axis(r)
                tilt = float(np.degrees(np.arccos(np.clip(ax @ normal / np.linalg.norm(ax), -1.0, 1.0))))
                if cat == "can":
                    tilt = min(tilt, 180.0 - tilt)
                rows.append({"scene": scene.name, "object": oid, "category": cat, "prompt": prompt, "tilt": tilt,
                             "rest_err": abs(tilt - rest), "confidence": float(r.confidence),
                             "ambiguous": bool(r.ambiguous), "evidence": r.extras.get("evidence", {})})
    print(f"{'model':14s} {'prompt':6s} {'objects':>7s} {'≤ 10°':>6s} {'conf med':>8s} {'AUROC':>6s} "
          f"{'confident-wrong':>15s} {'upside down':>11s}")
    for cat, model in MODELS.items():
        for prompt in ("mask", "box"):
            ok = [r for r in rows if r["category"] == cat and r["prompt"] == prompt and "tilt" in r]
            if not ok:
                continue
            err = np.array([r["rest_err"] for r in ok])
            conf = np.array([r["confidence"] for r in ok])
            cw = sum(1 for r in ok if r["rest_err"] > 30 and r["confidence"] > 0.5 and not r["ambiguous"])
            flipped = sum(1 for r in ok if r["tilt"] > 150)
            auc = auroc(conf, err <= 10)                                        # NaN where all are right or wrong
            print(f"{model:14s} {prompt:6s} {len(ok):7d} {np.mean(err <= 10):6.2f} {np.median(conf):8.2f} {auc:6.2f} "
                  f"{cw:15d} {flipped:11d}")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
