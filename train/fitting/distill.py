"""Partial-view training distilled from a trained complete-shape model (a measured deviation from the paper).

The paper trains the partial model with the one-directional min-of-60 chamfer from the partial points to the
predicted canonical shape. On a CPU budget that loss did not converge (airplane: 153° median after 3k steps) and on
squat categories it collapses the canonical shape into a round blob (cup: isotropy 0.94), because a blob explains
every partial view. Here a complete-shape model of the same category — itself trained without pose labels — is the
teacher: for every rendered view it sees the *complete* cloud in the same pose and gives a pose and a canonical shape
in its own learned frame. No ground-truth pose or canonical frame enters the loss; the renderer's pose is used only to
place the complete cloud where the partial view came from (the same known augmentation the complete-shape training
applies), and the student's frame is the teacher's learned frame (calibrated afterwards like any model).

Convention:
    Model units (metres / scale), camera frame. Teacher targets per view: ``rotations`` [V, 3, 3] (canonical →
    camera), ``translations`` [V, 3] (the complete cloud's centroid), ``shapes`` [V, M, 3] (teacher's canonical shape,
    centred at the origin). Loss terms are chamfer distances (mean squared, model units²).
"""
from __future__ import annotations

import json
import pathlib

import numpy as np
import torch
from tqdm import tqdm

from equipose.core.errors import ConfigError

from equipose.train.fitting.checkpoint import model_from_checkpoint

__all__ = ["complete_clouds", "teacher_targets", "view_teacher_targets", "is_view_teacher", "canonical_clouds"]


def complete_clouds(root, category: str, split: str, limit: int | None = None) -> list:
    """Complete point clouds [P_i, 3] per instance, in the frame and units (metres) the render cache posed them in."""
    from equipose.train.data.tabletop import is_tabletop, tabletop_sources
    if is_tabletop(category):
        return [np.asarray(c, np.float64) for _, _, c in tabletop_sources(root, category, split)[:limit]]
    from equipose.train.data.render_cache import modelnet_shapes
    return [np.asarray(c, np.float64) for _, _, c in modelnet_shapes(root, category, split, "npy1024", limit)]


def canonical_clouds(clouds: list, targets: dict, dataset, points: int = 512) -> np.ndarray:
    """Each instance's complete cloud in the teacher's canonical frame → [I, ``points``, 3] float32, model units.

    The teacher's pose of instance i (canonical → the render cache's object frame, model units) is read off its first
    view's targets: R_i = R_viewᵀ R_v, t_i = R_viewᵀ (t_v − t_view / scale); the cloud (metres, that object frame)
    goes back through it, y = R_iᵀ (c / scale − t_i), and keeps ``points`` farthest points. No pose labels: the
    render pose only undoes the known placement of the view, as in ``teacher_targets``."""
    from equipose.core.geometry import farthest_point_order
    inst = np.asarray(targets["instance"])                                            # [V]
    R_v = np.asarray(targets["rotations"], np.float64)                                # [V, 3, 3]
    t_v = np.asarray(targets["translations"], np.float64)                             # [V, 3]
    R_view = np.asarray(dataset.R, np.float64)                                        # [V, 3, 3]
    t_view = np.asarray(dataset.t, np.float64) / dataset.scale                        # [V, 3] model units
    out = np.empty((int(inst.max()) + 1, points, 3), np.float32)
    for i in range(len(out)):
        v = int(np.flatnonzero(inst == i)[0])
        R_i = R_view[v].T @ R_v[v]                                                    # [3, 3]
        t_i = R_view[v].T @ (t_v[v] - t_view[v])                                      # [3]
        c = np.asarray(clouds[i], np.float64) / dataset.scale                         # [P, 3] model units
        c = c[farthest_point_order(c, min(points, len(c)), start=0)]
        y = (c - t_i) @ R_i                                                           # [K, 3] rows: R_iᵀ (c − t_i)
        out[i] = y if len(y) == points else y[np.resize(np.arange(len(y)), points)]
    return out


def is_view_teacher(teacher) -> bool:
    """Whether ``teacher`` is a partial-view model — an exported ``.onnx`` file, run through the SDK, or a partial
    checkpoint — whose targets come from ``view_teacher_targets``, rather than a complete-shape checkpoint
    (``teacher_targets``)."""
    if str(teacher).endswith(".onnx"):
        return True
    ck = torch.load(teacher, map_location="cpu", weights_only=True)
    return bool(ck.get("partial", False))


def _sdk_view_poses(model_file, clean) -> tuple:
    """An exported model's poses of every view of ``clean`` through the SDK (its default profile: re-scoring, shape
    stages): (R [V, 3, 3] category frame, t [V, 3] model units camera frame and canonical shapes [V, M, 3], both in
    the network's learned frame, δR [3, 3]: the file's calibration, the refined one where it re-scores)."""
    from equipose.runtime.estimator import PoseEstimator
    est = PoseEstimator(model_file, threads=2)
    if abs(float(est.scale) - float(clean.scale)) > 1e-6:
        raise ConfigError(f"--teacher {model_file}: its scale {est.scale} m is not the training views' {clean.scale} m")
    rc = est.spec.refine_calibration
    dR, dt = (rc["rotation"], rc["translation"]) if rc is not None and est.refine else est.spec.calibration
    dR, dt = np.asarray(dR, np.float64), np.asarray(dt, np.float64)
    V = len(clean)
    R, t, shapes = np.empty((V, 3, 3)), np.empty((V, 3)), None
    for i in tqdm(range(V), desc="view teacher (SDK)"):
        r = est.predict_points(clean.raw(i)["points_m"])
        R[i] = r.rotation                                                              # [3, 3] category frame
        t[i] = r.translation / est.scale + r.rotation @ dt                             # t_cat = t − R_cat δt
        y = (np.asarray(r.canonical_shape_object, np.float64) / est.scale - dt) @ dR   # [M, 3] learned frame
        shapes = np.empty((V,) + y.shape, np.float32) if shapes is None else shapes
        shapes[i] = y
    return R, t, shapes, dR


@torch.no_grad()
def _network_view_poses(teacher, clean, batch_size: int = 32) -> tuple:
    """A partial checkpoint's best hypothesis on every view of ``clean`` (the plain network): (R [V, 3, 3] learned
    frame, t [V, 3] model units camera frame, canonical shapes [V, M, 3] learned frame)."""
    V = len(clean)
    R, t, shapes = np.empty((V, 3, 3)), np.empty((V, 3)), None
    for b in tqdm(range(0, V, batch_size), desc="view teacher (network)"):
        x = np.stack([clean.sample(i)["points"] for i in range(b, min(b + batch_size, V))])   # [b, N, 3]
        out = teacher(torch.from_numpy(x))
        best = out["hypothesis_scores"].argmin(1)                                      # [b]
        rows = torch.arange(len(best))
        R[b:b + len(best)] = out["hypothesis_rotations"][rows, best].numpy()
        t[b:b + len(best)] = out["hypothesis_translations"][rows, best].numpy()
        S = out["canonical_shape"].numpy().astype(np.float32)                          # [b, M, 3]
        shapes = np.empty((V,) + S.shape[1:], np.float32) if shapes is None else shapes
        shapes[b:b + len(best)] = S
    return R, t, shapes


def view_teacher_targets(teacher, dataset, clean, symmetry: str, cache_file=None, log=print) -> dict:
    """Targets from a partial-view teacher (e.g. a model itself, to fine-tune it on noisy depth): the layout of
    ``teacher_targets``, for every view of ``dataset``.

    The teacher poses every view of ``clean`` (the same instances rendered without the depth-sensor model): an
    exported ``.onnx`` file through the SDK (``_sdk_view_poses``), or a partial checkpoint's plain network. Each
    pose, carried back into the instance's object frame by the view's render pose (R_viewᵀ R,
    R_viewᵀ (t − t_view / scale)), is one estimate of the instance's frame. Their consensus in the category frame
    (where ``symmetry`` holds: the medoid view and the views within 15° of it,
    ``equipose.runtime.copies.consensus_pose``), taken back into the learned frame by the teacher's calibration, is
    that frame, carried to each view of ``dataset`` as ``teacher_targets`` carries the complete teacher's. The
    instance's shape is the mean canonical shape of the views that support the consensus (point by point, as the
    SDK's rotated copies average theirs); for a symmetric category, whose supporting views may spin about its axis,
    the shape of the view nearest the consensus. As there, the render pose only undoes the known placement of a view:
    no pose label enters.
    """
    from equipose.runtime.copies import consensus_pose
    from equipose.runtime.hypotheses import symmetric_distance_deg
    onnx_file = str(teacher).endswith(".onnx")
    if onnx_file:
        stamp = pathlib.Path(teacher).stat().st_mtime_ns
    else:
        net, ck = model_from_checkpoint(teacher)
        if not net.partial:
            raise ConfigError(f"--teacher {teacher}: a view teacher must be a partial-view model (mode partial)")
        stamp = ck.get("step")
    key = json.dumps({"view_teacher": str(pathlib.Path(teacher).resolve()), "stamp": stamp, "views": len(dataset),
                      "clean_views": len(clean), "symmetry": symmetry, "v": 5})
    if cache_file is not None and pathlib.Path(cache_file).is_file():
        z = np.load(cache_file)
        if str(z["key"]) == key:
            return {k: z[k] for k in ("rotations", "translations", "shapes", "instance")}
    if onnx_file:
        R, t, shapes_v, dR = _sdk_view_poses(teacher, clean)                            # R: category frame
    else:
        R, t, shapes_v = _network_view_poses(net, clean)
        cal = ck.get("calibration")
        if cal is None and symmetry != "none":
            raise ConfigError(f"--teacher {teacher}: a symmetric category's views agree about the category axis; "
                              "calibrate the teacher first (equipose calibrate)")
        dR = np.eye(3) if cal is None else np.asarray(cal["rotation"], np.float64)
        R = R @ dR.T                                                                   # category frame: R δRᵀ
    Rv = np.asarray(clean.R, np.float64)                                               # [V, 3, 3]
    tv = np.asarray(clean.t, np.float64) / clean.scale                                 # [V, 3] model units
    R_obj = np.transpose(Rv, (0, 2, 1)) @ R                                            # [V, 3, 3] R_viewᵀ R_cat
    t_obj = np.einsum("vji,vj->vi", Rv, t - tv)                                        # [V, 3] R_viewᵀ (t − t_view)
    inst_clean = np.asarray(clean.instance)                                            # [V]
    n_inst = int(max(inst_clean.max(), np.asarray(dataset.instance).max())) + 1
    R_inst, t_inst = np.empty((n_inst, 3, 3)), np.empty((n_inst, 3))
    shapes = np.empty((n_inst,) + shapes_v.shape[1:], np.float32)
    agree = []
    for i in range(n_inst):
        views = np.flatnonzero(inst_clean == i)
        if not len(views):
            raise ConfigError(f"view teacher: instance {i} has no clean view")
        R_c, t_c, support = consensus_pose(R_obj[views], t_obj[views], symmetry)
        R_inst[i], t_inst[i] = R_c @ dR, t_c                                            # learned frame: R_cat δR
        if symmetry == "none":
            shapes[i] = shapes_v[views[support]].mean(0)                               # point by point, as copies
        else:                                                                          # the consensus' own view
            shapes[i] = shapes_v[views[int(np.argmin(symmetric_distance_deg(R_c, R_obj[views], symmetry)))]]
        agree.append(float(support.mean()))
    inst = np.asarray(dataset.instance)                                                # [V']
    Rd = np.asarray(dataset.R, np.float64)                                             # [V', 3, 3]
    res = {"rotations": Rd @ R_inst[inst],                                             # [V', 3, 3]
           "translations": np.einsum("vij,vj->vi", Rd, t_inst[inst]) + dataset.t / dataset.scale,   # [V', 3]
           "shapes": shapes,                                                           # [I, M, 3]
           "instance": inst.astype(np.int64)}                                          # [V']
    if cache_file is not None:
        np.savez(cache_file, key=np.str_(key), **res)
    log(f"view teacher targets: {n_inst} instances from {len(clean)} clean views of {teacher} (views within 15° of "
        f"their instance's consensus: median {np.median(agree):.2f}), carried to {len(dataset)} views")
    return res


def _flip_templates(model, scale: float) -> dict:
    """``flip_templates`` of a model (name or .onnx) in units of ``scale`` metres: {"points" [T, M, 3], "axes"}."""
    from equipose.runtime.estimator import PoseEstimator
    est = PoseEstimator(model)
    ft = est.metadata.get("flip_templates")
    if ft is None:
        raise ConfigError(f"--teacher-flip {model}: the model has no flip_templates metadata "
                          "(python -m equipose.export.flip_templates)")
    return {"points": ft["points"] * est.scale / scale, "axes": ft["axes"]}


@torch.no_grad()
def teacher_targets(teacher_path, dataset, clouds: list, refine: int = 5, batch_size: int = 32,
                    cache_file=None, frame_priors: str = "", flip_model: str = "", log=print) -> dict:
    """Teacher pose for every view of ``dataset`` (a ``RenderedPartial``) and canonical shape for every instance.

    Returns ``{"rotations" [V, 3, 3], "translations" [V, 3] (model units, camera frame of each view),
    "shapes" [I, M, 3] (one per instance), "instance" [V] int64 (each view's row of "shapes")}``.

    The teacher sees each instance's complete cloud once, in the object frame the renderer posed it from; its pose is
    carried to every view by that view's render pose (R_view · R_teacher, R_view · c + t_view) — exact for the
    ICP-refined pose, and every view of an instance shares one frame. ``refine`` > 0: the teacher's ``refine`` best
    hypotheses are ICP-refined against its own canonical shape and re-ranked (``equipose.runtime.refine``), as the
    shipped complete models run. ``frame_priors`` (e.g. "footprint,mirror:x"): each instance's pose then goes through
    those steps on its complete cloud in the teacher's calibrated category frame (``equipose.runtime.frame_priors``),
    and its canonical shape turns with it (the posed shape stays where it was). ``flip_model``: a model whose metadata
    holds ``flip_templates`` (``equipose.runtime.flip``); each instance's pose first takes the candidate (itself or a
    half turn) those templates fit best. Cached in ``cache_file`` (keyed by the teacher file, the views, ``refine``,
    ``frame_priors`` and ``flip_model``).
    """
    from equipose.core.geometry import farthest_point_order
    from equipose.runtime.flip import flip_scores
    from equipose.runtime.frame_priors import apply_frame_priors, parse_steps
    from equipose.runtime.refine import refine_hypotheses
    teacher, ck = model_from_checkpoint(teacher_path)
    priors = parse_steps(frame_priors)
    flip = _flip_templates(flip_model, float(dataset.scale)) if flip_model else None
    if (priors is not None or flip is not None) and not ck.get("calibration"):
        raise ConfigError(f"--teacher {teacher_path}: frame priors need the teacher's calibration (equipose calibrate)")
    if priors is not None or flip is not None:                                       # learned → category frame
        dR = np.asarray(ck["calibration"]["rotation"], np.float64)
        dt = np.asarray(ck["calibration"]["translation"], np.float64)
    if teacher.partial:
        raise ConfigError(f"--teacher {teacher_path}: the teacher must be a complete-shape model (mode complete)")
    key = json.dumps({"teacher": str(pathlib.Path(teacher_path).resolve()), "teacher_step": ck.get("step"),
                      "views": len(dataset), "instances": len(clouds), "refine": refine, "v": 3,
                      **({"frame_priors": frame_priors} if priors is not None else {}),
                      **({"flip_model": str(flip_model)} if flip is not None else {})})
    if cache_file is not None and pathlib.Path(cache_file).is_file():
        z = np.load(cache_file)
        if str(z["key"]) == key:
            return {k: z[k] for k in ("rotations", "translations", "shapes", "instance")}
    n = teacher.num_points
    inputs = np.empty((len(clouds), n, 3), np.float32)
    for i, c in enumerate(clouds):
        c = c / dataset.scale                                                        # [P, 3] model units, object frame
        inputs[i] = c[farthest_point_order(c, n, start=0)]
    R_inst = np.empty((len(clouds), 3, 3))
    t_inst = np.empty((len(clouds), 3))
    shapes = None
    for b in tqdm(range(0, len(clouds), batch_size), desc="teacher targets"):
        out = teacher(torch.from_numpy(inputs[b:b + batch_size]))
        S = out["canonical_shape"].numpy().astype(np.float64)                        # [b, M, 3]
        if shapes is None:
            shapes = np.empty((len(clouds),) + S.shape[1:], np.float32)
        hR = out["hypothesis_rotations"].numpy().astype(np.float64)                  # [b, A, 3, 3]
        ht = out["hypothesis_translations"].numpy().astype(np.float64)               # [b, A, 3]
        hs = out["hypothesis_scores"].numpy().astype(np.float64)                     # [b, A]
        for j in range(len(S)):
            r, tt, s = hR[j], ht[j], hs[j]
            if refine > 0:
                r, tt, s = refine_hypotheses(inputs[b + j], S[j], r, tt, s, k=refine, iters=10, bidirectional=True)
            a = int(np.argmin(s))
            R_inst[b + j], t_inst[b + j] = r[a], tt[a]
            if priors is not None or flip is not None:                               # learned → category → learned
                c = clouds[b + j] / dataset.scale                                    # [P, 3] model units
                R_cat = r[a] @ dR.T
                if flip is not None:
                    _, fits, R_fit = flip_scores(c, R_cat, tt[a] - R_cat @ dt, flip["points"], flip["axes"],
                                                     partial=False)
                    R_cat = R_cat if int(np.argmin(fits)) == 0 else R_fit[int(np.argmin(fits))]
                if priors is not None:
                    R_cat, _ = apply_frame_priors(c - c.mean(0), R_cat, priors)
                Q = r[a].T @ (R_cat @ dR)                                            # learned-frame turn
                R_inst[b + j] = r[a] @ Q
                S[j] = S[j] @ Q                                                      # rows: Qᵀ y
        shapes[b:b + len(S)] = S
    inst = np.asarray(dataset.instance)                                               # [V]
    Rv = np.asarray(dataset.R, np.float64)                                            # [V, 3, 3]
    res = {"rotations": Rv @ R_inst[inst],                                            # [V, 3, 3]
           "translations": np.einsum("vij,vj->vi", Rv, t_inst[inst]) + dataset.t / dataset.scale,   # [V, 3]
           "shapes": shapes,                                                          # [I, M, 3]
           "instance": inst.astype(np.int64)}                                         # [V]
    if cache_file is not None:
        np.savez(cache_file, key=np.str_(key), **res)
    log(f"teacher targets: {len(clouds)} instances, {len(dataset)} views from {teacher_path} (refine {refine})")
    return res
