"""Train the turn classifier of a partial-view model (``equipose.runtime.turn_classifier``) without pose labels, and
store it in the model file (metadata ``turn_classifier``).

Data: the student's own rendered training views (``train/state/<name>``'s config: category, views) and, for each, the
pose its complete-shape teacher gives the instance's complete cloud (``equipose.train.fitting.distill.teacher_targets``,
with the lane's frame priors and flip templates; cached in the folder's ``teacher.npz``), carried into the category
frame by the teacher's calibration. No ground-truth pose is read. Each view enters as the SDK's model input
(``equipose.preprocess.prepare_points``: N FPS points, centred, model units) carried into the category frame by that
pose with a small random error (``noise_deg`` per axis, ``noise_t`` model units), and by its half turns about ``axes``;
a PointNet scores the sets and is trained so that the teacher-posed one scores highest (softmax over the sets).

With ``--student-frac F`` a share F of each batch is the model's **own** poses of those views instead (the file run
through the SDK, every stage but this one; cached in the folder's ``student_poses.npz``), each labelled with the
turn of it that lies closest to the teacher's pose: the classifier then learns on the pose errors it meets at run
time (an own pose off by 15° and turned is still to be turned back), not only on the teacher's clean ones. Own poses
farther than ``--student-max-deg`` from every turn of the teacher's are left out. Still no ground-truth pose.

Usage:
    python -m equipose.train.fitting.turn_classifier --model sdk/models/car-partial.onnx \\
        --state train/state/car-partial [--axes x,y,z] [--steps 2500] [--width 64] [--noise-deg 2] [--margin 0]
        [--ambiguous-margin 1] [--out F.onnx]
        [--student-frac 0.5] [--student-max-deg 45]
    python -m equipose.train.fitting.turn_classifier --model sdk/models/car-partial.int8.onnx \\
        --copy-from sdk/models/car-partial.onnx          # the same classifier into another file

Convention: rotations category → camera; translations model units in the centred camera frame of the model input.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import shutil
import sys
import time

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from equipose.core.metadata import decode_metadata, encode_turn_classifier
from equipose.preprocess import prepare_points
from equipose.runtime.hypotheses import HALF_TURNS, apply_calibration
from equipose.runtime.turn_classifier import turned_sets

__all__ = ["PointSetScore", "teacher_poses", "student_poses", "turn_labels", "training_inputs", "train_scorer",
           "add_to_model"]


class PointSetScore(torch.nn.Module):
    """Shared point MLP 3 → w → 2w → 4w (ReLU), max- and mean-pooled, head 8w → 2w → 1: a logit per point set
    [..., n, 3] → [...]. The layer layout is what ``equipose.runtime.turn_classifier.score_sets`` runs in numpy."""

    def __init__(self, width: int = 64, dropout: float = 0.3):
        super().__init__()
        w = int(width)
        self.point = torch.nn.ModuleList([torch.nn.Linear(3, w), torch.nn.Linear(w, 2 * w),
                                          torch.nn.Linear(2 * w, 4 * w)])
        self.head = torch.nn.ModuleList([torch.nn.Linear(8 * w, 2 * w), torch.nn.Linear(2 * w, 1)])
        self.dropout = torch.nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for layer in self.point:
            x = torch.relu(layer(x))                                                   # [..., n, F]
        g = torch.cat([x.max(-2).values, x.mean(-2)], -1)                              # [..., 2F]
        return self.head[1](self.dropout(torch.relu(self.head[0](g)))).squeeze(-1)     # [...]

    def layers(self) -> tuple:
        """(point layers, head layers) as [(W [out, in], b [out]) float32 numpy]."""
        def arr(mods):
            return [(m.weight.detach().numpy().astype(np.float32), m.bias.detach().numpy().astype(np.float32))
                    for m in mods]
        return arr(self.point), arr(self.head)


def teacher_poses(state_dir, log=print) -> tuple:
    """The student lane's rendered training views and the teacher's pose of each in the category frame.

    Returns (``RenderedPartial`` dataset, R [V, 3, 3] category → camera, t [V, 3] model units, camera frame)."""
    from equipose.train.fitting.checkpoint import load_checkpoint
    from equipose.train.data.datasets import RenderedPartial
    from equipose.train.fitting.distill import complete_clouds, teacher_targets
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.render_cache import ensure_cache
    from equipose.train.fitting.config import TrainConfig
    folder = pathlib.Path(state_dir)
    cfg = TrainConfig.from_sources(str(folder / "config.json"))
    if not cfg.teacher:
        raise ValueError(f"{folder}: the turn classifier learns from a teacher; this lane has none (config teacher)")
    repo = folder.resolve().parents[2]
    teacher = cfg.teacher if pathlib.Path(cfg.teacher).is_absolute() else str(repo / cfg.teacher)
    root = cfg.data_root or str(default_data_root())
    ds = RenderedPartial(ensure_cache(root, cfg.category, "train", views=cfg.views), 256, train=False)
    clouds = complete_clouds(root, cfg.category, "train", cfg.train_limit)
    tt = teacher_targets(teacher, ds, clouds, refine=cfg.teacher_refine, cache_file=folder / "teacher.npz",
                         frame_priors=cfg.teacher_priors, flip_model=cfg.teacher_flip, log=log)
    cal = load_checkpoint(teacher)["calibration"]
    R, t = apply_calibration(tt["rotations"], tt["translations"], cal["rotation"], cal["translation"])
    return ds, R, t


def student_poses(model_path, ds, cache_file=None, log=print) -> tuple:
    """The model file's own poses of the training views, every stage but the turn classifier (the stage being
    trained), as the SDK returns them: (R [V, 3, 3] category → camera, t [V, 3] metres, camera frame). Cached in
    ``cache_file`` under a hash of the file without its ``turn_classifier`` metadata (one network, one cache)."""
    import hashlib
    import onnx
    from equipose.runtime.estimator import PoseEstimator
    proto = onnx.load(str(model_path), load_external_data=False)
    keep = [p for p in proto.metadata_props if p.key != "turn_classifier"]
    del proto.metadata_props[:]
    proto.metadata_props.extend(keep)
    key = hashlib.sha1(proto.SerializeToString()).hexdigest()[:16] + f"_{len(ds)}"
    if cache_file is not None and pathlib.Path(cache_file).is_file():
        z = np.load(cache_file)
        if str(z["key"]) == key:
            return z["rotations"], z["translations"]
    est = PoseEstimator(str(model_path))
    est.metadata["turn_classifier"] = None
    Rs, ts, t0 = [], [], time.perf_counter()
    for i in range(0, len(ds), 16):
        for r in est.predict_points_batch([ds.raw(j)["points_m"] for j in range(i, min(len(ds), i + 16))]):
            Rs.append(r.rotation)
            ts.append(r.translation)
        if (i // 16) % 50 == 0:
            log(f"student poses: {len(Rs)}/{len(ds)} views ({time.perf_counter() - t0:.0f} s)")
    R, t = np.stack(Rs), np.stack(ts)
    if cache_file is not None:
        pathlib.Path(cache_file).parent.mkdir(parents=True, exist_ok=True)
        np.savez(cache_file, key=key, rotations=R, translations=t)
    return R, t


def turn_labels(R_student, R_teacher, axes) -> tuple:
    """(label [V] int: which of the student pose and its half turns about ``axes`` (0 = itself, k = axes[k − 1]) is
    closest to the teacher's pose, residual [V] degrees of that one)."""
    from equipose.core.geometry import rotation_angle_deg
    turns = [np.eye(3)] + [HALF_TURNS[a] for a in axes]
    err = np.stack([rotation_angle_deg(R_teacher, R_student @ H) for H in turns], 1)       # [V, 1 + A]
    return err.argmin(1), err.min(1)


def training_inputs(ds, R, t, num_points: int, scale: float) -> tuple:
    """(model inputs [V, N, 3] float32, translations [V, 3] in each input's centred frame, model units, input
    centres [V, 3] metres)."""
    X = np.empty((len(R), num_points, 3), np.float32)
    tc = np.empty((len(R), 3))
    centres = np.empty((len(R), 3))
    for i in range(len(R)):
        prep = prepare_points(ds.raw(i)["points_m"], num_points, scale)
        X[i] = prep.model_points
        centres[i] = prep.centre_m
        tc[i] = t[i] * ds.scale / scale - prep.centre_m / scale                       # teacher units → model units
    return X, tc, centres


def train_scorer(X, R, t, axes=("x", "y", "z"), steps: int = 2500, batch: int = 32, width: int = 64,
                 noise_deg: float = 2.0, noise_t: float = 0.01, lr: float = 1e-3, seed: int = 0,
                 student=None, student_frac: float = 0.5, log=print) -> PointSetScore:
    """Train a ``PointSetScore`` on inputs [V, N, 3] with poses R [V, 3, 3], t [V, 3] (see the module).

    ``student``: optional (R_s [V, 3, 3], t_s [V, 3] model units, labels [V], usable [V] bool): the model's own poses
    and which of their turns the teacher's pose is closest to; ``student_frac`` of each batch is drawn from them (the
    error distribution the stage meets at run time), the rest from the teacher poses (target: the pose itself)."""
    rng = np.random.default_rng(seed)
    torch.manual_seed(seed)
    net = PointSetScore(width)
    opt = torch.optim.Adam(net.parameters(), lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    if student is not None:
        R_s, t_s, lab, usable = student
        pool = np.flatnonzero(usable)                                                  # views the stage can fix
        if len(pool) == 0:
            raise ValueError("student poses: no usable view (all too far from every turn of the teacher's pose)")
        log(f"student poses: {len(pool)} usable views, turned {np.mean(lab[pool] != 0):.3f}")
    t0 = time.perf_counter()
    for step in range(steps):
        net.train()
        n_s = 0 if student is None else int(round(batch * student_frac))
        idx = np.concatenate([rng.integers(0, len(X), batch - n_s),
                              rng.choice(pool, n_s) if n_s else np.zeros(0, int)]).astype(int)
        dR = Rotation.from_rotvec(rng.normal(0, np.radians(noise_deg), (batch, 3))).as_matrix()   # [B, 3, 3]
        dt = rng.normal(0, noise_t, (batch, 3))
        sets, target = [], np.zeros(batch, np.int64)
        for b, i in enumerate(idx):
            if b < batch - n_s:
                sets.append(turned_sets(X[i], R[i] @ dR[b], t[i] + dt[b], axes))
            else:
                sets.append(turned_sets(X[i], R_s[i] @ dR[b], t_s[i] + dt[b], axes))
                target[b] = lab[i]
        logits = net(torch.from_numpy(np.stack(sets)))                                # [B, 1 + A]
        loss = torch.nn.functional.cross_entropy(logits, torch.from_numpy(target))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if (step + 1) % 500 == 0 or step + 1 == steps:
            log(f"turn classifier step {step + 1}/{steps}: loss {loss.item():.4f} ({time.perf_counter() - t0:.0f} s)")
    net.eval()
    return net


def _metadata_props(model_path) -> dict:
    """The raw metadata strings of an ONNX file (key → value)."""
    import onnx
    return {p.key: p.value for p in onnx.load(str(model_path), load_external_data=False).metadata_props}


def _write(model_path, value: str, out=None) -> pathlib.Path:
    """Store a ``turn_classifier`` metadata value in ``model_path`` (or in a copy of it at ``out``)."""
    from equipose.export.onnx_export import update_metadata
    path = pathlib.Path(model_path)
    if out is not None and pathlib.Path(out) != path:
        shutil.copyfile(path, out)
        path = pathlib.Path(out)
    return update_metadata(path, turn_classifier=value)


def add_to_model(model_path, net: PointSetScore, axes, margin: float, ambiguous_margin: float, source: dict,
                 out=None) -> pathlib.Path:
    """Write the scorer into ``model_path``'s metadata (or into a copy at ``out``)."""
    point, head = net.layers()
    return _write(model_path, encode_turn_classifier(point, head, axes, margin, ambiguous_margin, source), out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m equipose.train.fitting.turn_classifier",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--model", required=True, help="the partial-view .onnx file the classifier is added to")
    ap.add_argument("--state", help="its training-state folder (train/state/NAME: config, teacher)")
    ap.add_argument("--copy-from",
                    help="instead of training: copy the classifier of this model file (e.g. fp32 → int8)")
    ap.add_argument("--axes", default="x,y,z")
    ap.add_argument("--steps", type=int, default=2500)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--noise-deg", type=float, default=2.0)
    ap.add_argument("--margin", type=float, default=0.0, help="logits a turn must win by to replace the pose")
    ap.add_argument("--ambiguous-margin", type=float, default=1.0, help="lead below which the result is ambiguous")
    ap.add_argument("--student-frac", type=float, default=0.0,
                    help="share of each batch posed by the model's own poses of the training views (labelled by "
                         "the teacher's turn); 0: teacher poses only")
    ap.add_argument("--student-max-deg", type=float, default=45.0,
                    help="own poses farther than this from every turn of the teacher's pose are left out")
    ap.add_argument("--out", help="write a copy here instead of changing --model")
    ap.add_argument("--threads", type=int, default=1)
    a = ap.parse_args(argv)
    if a.copy_from:
        value = _metadata_props(a.copy_from).get("turn_classifier")
        if not value:
            raise SystemExit(f"--copy-from {a.copy_from}: that file has no turn classifier")
        print(f"turn classifier of {a.copy_from} → {_write(a.model, value, a.out)}")
        return 0
    if not a.state:
        raise SystemExit("--state is required (the lane whose views and teacher train the classifier)")
    torch.set_num_threads(a.threads)
    axes = [s.strip() for s in a.axes.split(",") if s.strip()]
    if not axes or any(x not in HALF_TURNS for x in axes):
        raise SystemExit(f"--axes: some of x, y, z, got {a.axes!r}")
    meta = decode_metadata(_metadata_props(a.model), source=a.model)
    if not meta["partial"]:
        raise SystemExit(f"{a.model}: the turn classifier is for partial-view models")
    ds, R, t = teacher_poses(a.state)
    scale = float(meta["scale"])
    X, tc, centres = training_inputs(ds, R, t, int(meta["num_points"]), scale)
    print(f"{len(X)} training views of {meta['category']} posed by the teacher", flush=True)
    student = None
    source = {"state": str(a.state), "views": len(X), "steps": a.steps, "width": a.width, "noise_deg": a.noise_deg,
              "labels": "teacher"}
    if a.student_frac > 0:
        R_s, t_s = student_poses(a.model, ds, cache_file=pathlib.Path(a.state) / "student_poses.npz")
        lab, resid = turn_labels(R_s, R, axes)
        usable = resid <= a.student_max_deg
        student = (R_s, (t_s - centres) / scale, lab, usable)
        print(f"model's own poses of the training views: turned against the teacher {np.mean(lab != 0):.3f}, "
              f"residual median {np.median(resid):.1f}°, usable (≤ {a.student_max_deg:g}°) {usable.mean():.3f}")
        source.update(student_frac=a.student_frac, student_max_deg=a.student_max_deg)
    net = train_scorer(X, R, tc, axes, steps=a.steps, width=a.width, noise_deg=a.noise_deg, student=student,
                       student_frac=a.student_frac)
    path = add_to_model(a.model, net, axes, a.margin, a.ambiguous_margin, source, out=a.out)
    print(f"turn classifier ({', '.join(axes)}; margin {a.margin}) → {path}")
    print(json.dumps(source))
    return 0


if __name__ == "__main__":
    sys.exit(main())
