"""Frame calibration: register the network's learned canonical frame to the category frame (spec §6, fixed).

Convention:
    The network's selected pose on an input already in the category frame (R_gt = I, t_gt = 0) is the frame offset
    (δR, δt): X_canon ≈ δR · Z + δt. Over many canonical training inputs the δR agree (up to outliers: flips,
    failures), so a robust consensus gives the calibration. At test time, for a prediction (R, t):
        R̂ = R · δRᵀ,  t̂ = t − R̂ · δt     (x = R̂ x_obj + t̂, the category frame).
    Rotations [..., 3, 3] act on column vectors; translations in model units.
    Symmetric categories (``continuous:<axis>``): only the category axis is calibrated. Its direction in the learned
    frame is u = δRᵀ e_axis; the consensus u is completed to a right-handed frame with u as that axis.
    Stored in the checkpoint as ``{"rotation": 3×3, "translation": 3, "inlier_fraction", "n", "symmetry", ...}``.
"""
from __future__ import annotations

import numpy as np

from equipose.core.errors import ConfigError
from equipose.core.geometry import axis_angle_deg, rotation_angle_deg

__all__ = ["so3_mean", "ransac_rotation", "ransac_axis", "ransac_translation", "calibrate_offsets",
           "apply_calibration", "frame_with_axis", "AXES", "calibrate_onnx_refined"]

AXES = {"x": 0, "y": 1, "z": 2}
# pipeline stages that act in the category frame: off while a calibration measures the raw learned-frame poses
CATEGORY_FRAME_STAGES = ("rest_facet", "frame_priors", "flip", "turn", "cylinder", "handle")


def so3_mean(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotations [K, 3, 3] → [3, 3] (SVD projection of the sum, det fixed to +1)."""
    U, _, Vt = np.linalg.svd(np.sum(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def ransac_rotation(Rs: np.ndarray, iters: int = 100, sample: int = 5, thresh_deg: float = 5.0,
                    coarse_deg: float = 30.0, seed: int = 0) -> tuple:
    """Consensus rotation of [K, 3, 3]: (chordal mean of the final inliers [3, 3], inlier mask [K]).

    Hypotheses: ``iters`` means of ``sample`` random rotations plus up to 2·``iters`` single rotations; the one with
    the most inliers within ``coarse_deg``
    wins (the densest mode, also for a coarsely trained network whose offsets spread over more than 5°); it is then
    refit on its inliers while the threshold shrinks to ``thresh_deg`` (5°, spec §6). The reference kept the
    5-sample hypothesis without a refit. ``coarse_deg = thresh_deg`` gives the plain single-threshold RANSAC.
    """
    Rs = np.asarray(Rs, np.float64)
    K = len(Rs)
    if K == 0:
        raise ConfigError("calibration needs at least one prediction")
    rng = np.random.default_rng(seed)
    coarse = max(coarse_deg, thresh_deg)
    best, best_hyp = None, None
    hyps = [so3_mean(Rs[rng.choice(K, size=min(sample, K), replace=False)]) for _ in range(iters)]
    hyps += list(Rs[rng.choice(K, size=min(K, 2 * iters), replace=False)])   # single-sample hypotheses find modes
    for hyp in hyps:
        inl = rotation_angle_deg(Rs, hyp) < coarse
        if best is None or inl.sum() > best.sum():
            best, best_hyp = inl, hyp
    mean = best_hyp
    for th in np.geomspace(coarse, thresh_deg, 4) if coarse > thresh_deg else [thresh_deg]:
        for _ in range(5):                                # refit on inliers until stable
            inl = rotation_angle_deg(Rs, mean) < th
            if not inl.any():
                break
            new = so3_mean(Rs[inl])
            if rotation_angle_deg(new, mean) < 1e-6:
                break
            mean = new
    inl = rotation_angle_deg(Rs, mean) < thresh_deg
    return mean, inl


def ransac_axis(us: np.ndarray, iters: int = 100, sample: int = 5, thresh_deg: float = 5.0, unsigned: bool = False,
                seed: int = 0) -> tuple:
    """Consensus direction of unit vectors [K, 3] → (unit [3], inlier mask [K]). ``unsigned``: u ≡ −u."""
    us = np.asarray(us, np.float64)
    us = us / np.linalg.norm(us, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    K = len(us)

    def mean_dir(v):
        if unsigned:   # principal direction of the scatter matrix
            w, V = np.linalg.eigh(v.T @ v)
            return V[:, -1]
        m = v.sum(0)
        return m / max(np.linalg.norm(m), 1e-12)

    best = None
    for _ in range(iters):
        hyp = mean_dir(us[rng.choice(K, size=min(sample, K), replace=False)])
        inl = axis_angle_deg(us, hyp, unsigned=unsigned) < thresh_deg
        if best is None or inl.sum() > best.sum():
            best = inl
    if not best.any():
        best = np.ones(K, bool)
    for _ in range(3):
        m = mean_dir(us[best])
        new = axis_angle_deg(us, m, unsigned=unsigned) < thresh_deg
        if not new.any() or (new == best).all():
            break
        best = new
    return mean_dir(us[best]), best


def ransac_translation(ts: np.ndarray, iters: int = 100, sample: int = 5, thresh: float = 0.025,
                       seed: int = 0) -> tuple:
    """Consensus translation of [K, 3] → (mean of inliers [3], inlier mask [K]); inlier if ‖t − hyp‖ < thresh."""
    ts = np.asarray(ts, np.float64)
    rng = np.random.default_rng(seed)
    K = len(ts)
    best = None
    for _ in range(iters):
        hyp = ts[rng.choice(K, size=min(sample, K), replace=False)].mean(0)
        inl = np.linalg.norm(ts - hyp, axis=1) < thresh
        if best is None or inl.sum() > best.sum():
            best = inl
    if not best.any():
        best = np.ones(K, bool)
    return ts[best].mean(0), best


def frame_with_axis(u: np.ndarray, axis: int = 2) -> np.ndarray:
    """A rotation δR whose row ``axis`` is the unit vector u (so δRᵀ e_axis = u), right-handed."""
    u = np.asarray(u, np.float64) / np.linalg.norm(u)
    helper = np.eye(3)[int(np.argmin(np.abs(u)))]
    a = np.cross(u, helper)
    a /= np.linalg.norm(a)
    b = np.cross(u, a)
    rows = [None, None, None]
    rows[axis], rows[(axis + 1) % 3], rows[(axis + 2) % 3] = u, a, b     # cyclic order keeps det = +1
    return np.stack(rows)


def calibrate_offsets(dR: np.ndarray, dt: np.ndarray, symmetry: str = "none", unsigned_axis: bool = False,
                      seed: int = 0) -> dict:
    """Calibration dict from per-input offsets dR [K, 3, 3], dt [K, 3] (predictions on category-frame inputs)."""
    dR, dt = np.asarray(dR, np.float64), np.asarray(dt, np.float64)
    if symmetry.startswith("continuous:"):
        ax = symmetry.split(":", 1)[1]
        if ax not in AXES:
            raise ConfigError(f"symmetry axis must be x, y or z, got {symmetry!r}")
        us = dR[:, AXES[ax], :]                            # rows = δRᵀ e_axis  [K, 3]
        u, inl = ransac_axis(us, unsigned=unsigned_axis, seed=seed)
        R = frame_with_axis(u, AXES[ax])
    elif symmetry == "none":
        R, inl = ransac_rotation(dR, seed=seed)
    else:
        raise ConfigError(f"unsupported symmetry {symmetry!r}")
    # δt: in the category frame X_canon ≈ R̂ Z' ... use t̂ = t − R̂ δt with R̂ = I on canonical inputs ⇒ δt = t − 0
    t, tin = ransac_translation(dt, seed=seed)
    return {"rotation": R.tolist(), "translation": t.tolist(), "inlier_fraction": float(inl.mean()),
            "translation_inlier_fraction": float(tin.mean()), "n": int(len(dR)), "symmetry": symmetry,
            "method": "ransac-mode30-refit5"}


def apply_calibration(R: np.ndarray, t: np.ndarray, calibration: dict | None) -> tuple:
    """Map predictions R [..., 3, 3], t [..., 3] from the learned frame to the category frame."""
    if not calibration:
        return np.asarray(R), np.asarray(t)
    dR = np.asarray(calibration["rotation"], np.float64)
    dt = np.asarray(calibration["translation"], np.float64)
    Rh = np.asarray(R, np.float64) @ dR.T
    th = np.asarray(t, np.float64) - Rh @ dt
    return Rh, th


def calibrate_onnx_refined(model_path, canonical_points: np.ndarray, k: int = 5, iters: int = 10,
                           unsigned_axis: bool = False, seed: int = 0, copies: int = 1,
                           visibility: float | None = None, polish: int = 0, densify: int = 0) -> dict:
    """Calibration of an exported model *as the SDK runs it with ICP re-scoring* (``PoseEstimator(refine=k)``).

    Convention: ``canonical_points`` [K, N', 3] model units, category frame (identity pose, as ``calibrate_model``).
    Each input (as metres about the origin) goes through ``PoseEstimator.predict_points`` with ``refine=k`` and an
    identity calibration, so the selected poses are the raw learned-frame offsets (δR, δt in model units about the
    input origin) of exactly the SDK's path; they are reduced with ``calibrate_offsets``. Returns that dict plus
    ``k``, ``iters`` and ``copies`` (rotated input copies, ``PoseEstimator(copies=...)``; the ``refine_calibration``
    metadata entry), and ``visibility`` (recorded for the SDK's view-aware re-scoring; the calibration itself runs
    without it: its inputs sit at the origin, with no camera to see them from, and the re-scoring only chooses
    between distinct poses, which leaves the frame offset of the right ones as it is), and ``polish`` (ICP iterations
    on the selected pose, ``PoseEstimator(polish=...)``) and ``densify`` (the ICP template's midpoints,
    ``PoseEstimator(densify=...)``): the calibration runs with both. The stages that work in the category frame
    (``CATEGORY_FRAME_STAGES``: the file's flip templates, turn classifier, frame priors, rest facet, cylinder and
    handle, which an int8 copy carries from its fp32 file) are off: the poses here are raw. torch-free.
    """
    from equipose.runtime.estimator import PoseEstimator

    pts = np.asarray(canonical_points, np.float64)
    if pts.ndim != 3 or pts.shape[-1] != 3:
        raise ConfigError(f"canonical_points must be [K, N, 3], got {pts.shape}")
    est = PoseEstimator(model_path, threads=1, refine=int(k), refine_iters=int(iters), copies=int(copies),
                        visibility=None, polish=int(polish), densify=int(densify),
                        stages={name: False for name in CATEGORY_FRAME_STAGES})
    est.calibration_rotation, est.calibration_translation = np.eye(3), np.zeros(3)     # raw, learned-frame poses
    res = [r for i in range(0, len(pts), 32)                                          # batches of 32: bounded memory
           for r in est.predict_points_batch([p * est.scale for p in pts[i:i + 32]])]  # metres, object at the origin
    dR = np.stack([r.rotation for r in res])                                          # [K, 3, 3]
    dt = np.stack([r.translation for r in res]) / est.scale                           # [K, 3] model units
    cal = calibrate_offsets(dR, dt, symmetry=est.symmetry, unsigned_axis=unsigned_axis, seed=seed)
    return {"k": int(k), "iters": int(iters), "copies": int(copies), "polish": int(polish), "densify": int(densify),
            "visibility": None if visibility is None else float(visibility), **cal}
