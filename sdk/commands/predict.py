"""``equipose predict``: poses on a depth source (PNG folder, .mcap, .pcd, ``oak``, or one RGB-D pair: ``--depth``
``--rgb`` ``--intrinsics`` ``--depth-unit``), printed and/or drawn.

Convention: one output line per object per frame (``frame N: object K: <category> R(rotvec°)=[...] t(m)=[...]
confidence=C``), or with ``--json`` one JSON object per frame (``TrackRecord.to_dict()``). ``--out DIR`` writes
``DIR/NNNNNN.png`` overlays (axes + oriented box) and ``DIR/results.jsonl``. Bad frames are reported on stderr and the
stream continues. Exit status: 0 if at least one pose was produced, 1 if none, 2 for unusable arguments/model/source.
"""
from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

from equipose.core.errors import ConfigError, RegionError

__all__ = ["add_arguments", "run", "parse_box", "parse_up", "load_mask"]


def parse_box(text: str) -> tuple:
    """``"x,y,w,h"`` → (x, y, w, h) floats. Raises ``RegionError``."""
    try:
        vals = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise RegionError(f"--box {text!r}: expected four numbers x,y,w,h") from None
    if len(vals) != 4:
        raise RegionError(f"--box {text!r}: expected four numbers x,y,w,h, got {len(vals)}")
    return vals


def parse_up(text: str | None):
    """``--up``: None, ``"plane"`` or ``"x,y,z"`` (camera frame) → what ``PoseEstimator.predict(up=...)`` takes.
    Raises ``ConfigError``."""
    if text is None or text == "plane":
        return text
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != 3:
        raise ConfigError(f"--up {text!r}: expected 'plane' or a camera-frame direction x,y,z (e.g. 0,-1,0 for a "
                          "level camera)")
    from equipose.runtime.upright import check_up
    return check_up(vals)


def _unit(text: str):
    """``--model-points-unit``: a unit name, or metres per file unit as a number."""
    try:
        return float(text)
    except ValueError:
        return text


def load_mask(path) -> "np.ndarray":
    """A mask image (any non-zero pixel = object) → [H, W] bool. Raises ``RegionError``."""
    import cv2
    m = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if m is None:
        raise RegionError(f"--mask {path}: not a readable image file")
    if m.ndim == 3:
        m = m.max(axis=2)
    return m > 0


def add_arguments(p):
    p.add_argument("--model", "-m", help="equipose .onnx model or a shipped model name (default: the bundled demo model, cup-tabletop)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--source", "-s",
                     help="PNG folder (with intrinsics.json), .mcap recording, .pcd file/folder, or 'oak'")
    src.add_argument("--depth", help="one depth PNG (uint16); with --intrinsics, optionally --rgb and --depth-unit")
    p.add_argument("--rgb", help="with --depth: the registered colour image (for overlays)")
    p.add_argument("--intrinsics", help="with --depth: fx,fy,cx,cy of the depth image, or a JSON file "
                                        "({\"K\": 3×3, \"width\", \"height\"} or {\"fx\", \"fy\", \"cx\", \"cy\"})")
    p.add_argument("--depth-unit", dest="depth_unit", default="mm",
                   help="with --depth: mm (default), m, or metres per stored unit (e.g. 0.0001)")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--box", action="append", metavar="x,y,w,h", help="object box in pixels (repeat for several)")
    g.add_argument("--mask", action="append", metavar="FILE", help="object mask image (repeat for several)")
    g.add_argument("--auto", action="store_true", help="find objects on a table automatically (plane + clusters)")
    p.add_argument("--out", "-o", help="folder for overlay PNGs and results.jsonl")
    p.add_argument("--overwrite", action="store_true", help="replace an existing results.jsonl in --out")
    p.add_argument("--json", action="store_true", help="print one JSON object per frame instead of text lines")
    p.add_argument("--profile", default="default", choices=["fast", "default", "accurate"],
                   help="speed / accuracy point of the pipeline (PoseEstimator(profile=...); docs/benchmarks.md)")
    p.add_argument("--threads", type=int, default=None, help="onnxruntime thread budget (default: all cores; a single object "
                   "of a light model runs on one)")
    p.add_argument("--max-frames", type=int, default=None, help="stop after this many frames")
    p.add_argument("--up", metavar="plane|x,y,z", default=None,
                   help="up prior for objects standing in their rest pose: 'plane' (the frame's table/floor) or a "
                        "camera-frame up direction, e.g. from an IMU (see PoseEstimator.predict)")
    p.add_argument("--model-points", dest="model_points", metavar="FILE",
                   help="instance-level mode: the object's own model (.xyz/.txt/.csv/.pts, .npy, .pcd points; .obj/.ply "
                        "meshes, sampled on their surface) in its CAD frame; poses are that model's "
                        "(PoseEstimator(model_points=...))")
    p.add_argument("--model-points-unit", dest="model_points_unit", default="m",
                   help="with --model-points: m (default), cm, mm, or metres per file unit")
    p.add_argument("--smoothing", type=float, default=0.0, help="temporal smoothing α in [0, 1) (default 0: raw)")
    p.add_argument("--hold-turns", dest="hold_turns", action="store_true",
                   help="a frame whose result is ambiguous keeps the track's half turn (and a mug with its handle out "
                        "of view the track's azimuth): PoseEstimator.track(hold_turns=True); default: each frame its own")


def run(args) -> int:
    from equipose.runtime.estimator import PoseEstimator

    if args.max_frames is not None and args.max_frames < 1:
        raise ConfigError("--max-frames must be ≥ 1")
    model = args.model
    if model is None:
        from equipose.models import demo_model_path
        model = demo_model_path()
    points = None
    if args.model_points:
        from equipose.core.model_points import load_model_points
        points = load_model_points(args.model_points, _unit(args.model_points_unit))
    est = PoseEstimator(model, threads=args.threads, profile=args.profile, model_points=points)
    if est.random_init:
        print(f"note: {pathlib.Path(model).name} has random weights (an export for tests or benchmarks): "
              "its poses are meaningless", file=sys.stderr)
    up = parse_up(args.up)
    boxes = [parse_box(b) for b in args.box] if args.box else None
    masks = [load_mask(m) for m in args.mask] if args.mask else None
    out = pathlib.Path(args.out) if args.out else None
    if out and (out / "results.jsonl").exists() and not args.overwrite:
        raise ConfigError(f"{out / 'results.jsonl'} exists; choose another --out or pass --overwrite")
    n_poses, written, jsonl, made = 0, [], None, False
    try:
        with _open(args) as src:                                               # a bad source fails before any output
            if out:
                made = not out.exists()
                out.mkdir(parents=True, exist_ok=True)
                jsonl = open(out / ".results.jsonl.partial", "w")
            for rec in est.track(src, boxes=boxes, masks=masks, auto=args.auto, smoothing=args.smoothing,
                                 max_frames=args.max_frames, keep_frames=out is not None, up=up,
                                 hold_turns=args.hold_turns):
                n_poses += len(rec.poses)
                d = rec.to_dict()
                if jsonl:
                    jsonl.write(json.dumps(d) + "\n")
                if args.json:
                    print(json.dumps(d), flush=True)
                else:
                    for pose in rec.poses:
                        print(f"frame {rec.frame_index}: {pose.summary()}", flush=True)
                    if not rec.poses and not rec.errors:
                        print(f"frame {rec.frame_index}: no object found", flush=True)
                for e in rec.errors:
                    who = "" if e.object_id is None else f" object {e.object_id}"
                    print(f"frame {rec.frame_index}{who}: {e.error}: {e.message}", file=sys.stderr, flush=True)
                if out and rec.frame is not None and rec.poses:
                    written.append(out / f"{rec.frame_index:06d}.png")
                    _write_overlay(written[-1], rec)
    except KeyboardInterrupt:                                                   # live camera: Ctrl-C ends the run
        print("stopped", file=sys.stderr)
    finally:
        if jsonl:
            jsonl.close()
            _finish_output(out, n_poses, written, made)
    if out and n_poses:
        print(f"{len(written)} overlay(s) and results.jsonl written to {out}", file=sys.stderr)
    elif not n_poses:
        print("no pose was produced: check the model, the region (--box / --mask / --auto) and the depth frames "
              "(messages above)", file=sys.stderr)
    return 0 if n_poses else 1


def _open(args):
    """The frame source of ``--source``, or the single RGB-D pair of ``--depth`` / ``--rgb`` / ``--intrinsics``."""
    from equipose.sources import open_source
    from equipose.sources.rgbd import RgbdPairSource, parse_depth_unit, parse_intrinsics
    if args.depth is None:
        for flag in ("rgb", "intrinsics"):
            if getattr(args, flag):
                raise ConfigError(f"--{flag} goes with --depth (a single RGB-D pair); a --source brings its own")
        return open_source(args.source)
    if not args.intrinsics:
        raise ConfigError("--depth needs --intrinsics fx,fy,cx,cy (pixels of the depth image) or a JSON file")
    K, size = parse_intrinsics(args.intrinsics)
    return RgbdPairSource(args.depth, K, rgb=args.rgb, depth_unit=parse_depth_unit(args.depth_unit), image_size=size)


def _finish_output(out: pathlib.Path, n_poses: int, written: list, made: bool) -> None:
    """Keep ``results.jsonl`` only when poses were produced; otherwise remove what this run wrote (the partial
    results, overlays, the folder if it created it), so that a retry is not blocked."""
    partial = out / ".results.jsonl.partial"
    if n_poses:
        partial.replace(out / "results.jsonl")
        return
    partial.unlink(missing_ok=True)
    for p in written:
        p.unlink(missing_ok=True)
    if made and not any(out.iterdir()):
        out.rmdir()


def _write_overlay(path, rec):
    import cv2

    from equipose.preprocess import check_intrinsics
    from equipose.runtime.overlay import draw_poses

    f = rec.frame
    K = check_intrinsics(f.K, np.shape(f.depth)[:2], f.image_size)
    cv2.imwrite(str(path), draw_poses(f.rgb if f.rgb is not None else f.depth, K, rec.poses))
