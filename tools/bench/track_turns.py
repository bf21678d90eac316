"""Half turns while tracking: rendered sequences of a slowly turning test shape through ``PoseEstimator.track``.

    python tools/bench/track_turns.py --model car-partial [--category car] [--sequences 20] [--frames 30]
        [--step-deg 2] [--seed 7] [--no-hold]

Each sequence renders one ModelNet test shape (partial depth, the test views' camera) turning by ``--step-deg`` per
frame about a random axis from a random start, and tracks it with the visible mask as the region. It prints the share
of frames whose pose is turned (rotation error > 150°), the share of frame-to-frame changes between turned and not
turned (flip-flops), and the share flagged ``ambiguous``. ``--no-hold`` tracks with ``hold_turns=False``.

Convention: angles in degrees; shares of all tracked frames.
"""
from __future__ import annotations

import argparse

import numpy as np
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator
from equipose.eval.metrics import FLIP_DEG, rotation_errors
from equipose.sources.base import Frame
from equipose.train.data.modelnet import default_data_root
from equipose.train.data.render import CATEGORY_DISTANCE, RenderSettings, camera_matrix, render_frame, sample_pose
from equipose.train.data.render_cache import modelnet_shapes


def sequence(shape: dict, rng, settings: RenderSettings, K: np.ndarray, frames: int, step_deg: float) -> tuple:
    """([Frame], [mask [H, W] bool], [R [3, 3]]) of ``shape`` turning about a random axis from a random pose."""
    R0, t = sample_pose(rng, settings)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    out, masks, Rs = [], [], []
    for k in range(frames):
        R = Rotation.from_rotvec(np.radians(step_deg * k) * axis).as_matrix() @ R0
        depth, mask = render_frame(shape, R, t, K, (settings.width, settings.height))
        out.append(Frame(depth=depth, K=K, index=k))
        masks.append(mask)
        Rs.append(R)
    return out, masks, Rs


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--category", help="ModelNet category of the test shapes (default: the model's)")
    ap.add_argument("--sequences", type=int, default=20)
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--step-deg", dest="step_deg", type=float, default=2.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--no-hold", dest="hold", action="store_false", help="track with hold_turns=False")
    a = ap.parse_args(argv)
    est = PoseEstimator(a.model)
    category = a.category or est.category
    shapes = modelnet_shapes(default_data_root(), category, "test", "npy1024", None)
    settings = RenderSettings(distance=CATEGORY_DISTANCE.get(category, 2.0))
    K = camera_matrix(settings.width, settings.height, settings.fov_y_deg)
    rng = np.random.default_rng(a.seed)
    n = turned = flips = flagged = 0
    for _ in range(a.sequences):
        _, shape, _ = shapes[int(rng.integers(len(shapes)))]
        frames, masks, Rs = sequence(shape, rng, settings, K, a.frames, a.step_deg)
        records = est.track(iter(frames), regions=lambda f: [{"box": None, "mask": masks[f.index]}],
                            hold_turns=a.hold)
        poses = [(k, r.poses[0]) for k, r in enumerate(records) if r.poses]
        err = rotation_errors(np.stack([p.rotation for _, p in poses]), np.stack([Rs[k] for k, _ in poses]))
        t = err > FLIP_DEG                                                      # [frames] turned
        n, turned, flips = n + len(t), turned + int(t.sum()), flips + int(np.sum(t[1:] != t[:-1]))
        flagged += sum(bool(p.ambiguous) for _, p in poses)
    print(f"{a.model} ({'hold_turns' if a.hold else 'no hold'}): {n} frames of {a.sequences} sequences; turned "
          f"{turned / n:.3f}, flip-flops {flips / n:.3f} per frame, ambiguous {flagged / n:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
