"""Labelled real RGB-D scenes (mOSD / OSD Kinect clouds): support plane, per-object points, axis-vs-table angles.

Pure numpy (no torch, no onnxruntime); ``load_labelled_scene`` needs pypcd4 like ``equipose.sources.pcd``.

Convention:
    Points are in the OpenCV camera frame (x right, y down, z forward), metres; NaN or z ≤ 0 = invalid.
    Angles are degrees. Labels follow mOSD: 0 invalid, 1–9 (parts of) the supporting table, 20–29 (parts of) the
    first object, 30–39 the second, …: object id = ``label // 10`` for ``label ≥ 20`` (disjoint parts of one object
    carry different labels in the same decade and are merged). A plane is ``normal · x = offset`` with a unit normal;
    the table normal is oriented "up", towards the camera: ``normal · (−centroid) > 0``. Axis signs are arbitrary, so
    an axis-vs-normal angle is folded to [0, 90] with ``|dot|``; a resting cylinder is upright (0°) or lying (90°),
    and its deviation is ``min(a, 90 − a)`` ∈ [0, 45].
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass

import numpy as np

from equipose.core.errors import InvalidPointsError, SourceError, TooFewPointsError

__all__ = [
    "LabelledScene", "Plane", "AxisAngle", "load_labelled_scene", "fit_plane", "orient_towards_camera", "table_plane",
    "group_objects", "axis_table_angle", "principal_axis", "summarize_deviations", "random_axis_fraction_within",
    "random_axis_summary",
]

TABLE_LABELS = range(1, 10)
FIRST_OBJECT_LABEL = 20


@dataclass
class LabelledScene:
    """One organized labelled cloud.

    Convention: ``xyz`` [H, W, 3] float32 metres, camera frame (NaN = invalid); ``label`` [H, W] int64; ``valid``
    [H, W] bool (finite, z > 0); ``rgb`` [H, W, 3] BGR uint8 or None; ``depth`` [H, W] uint16 mm; ``K`` [3, 3]
    pinhole intrinsics recovered from the cloud (``intrinsics_from_organized``).
    """
    name: str
    xyz: np.ndarray
    label: np.ndarray
    valid: np.ndarray
    rgb: np.ndarray | None
    depth: np.ndarray
    K: np.ndarray


@dataclass
class Plane:
    """A fitted plane ``normal · x = offset``.

    Convention: ``normal`` [3] unit, ``offset`` metres, ``centroid`` [3] metres (mean of the inliers), ``inliers``
    [P] bool over the input points, ``rms`` metres (point-to-plane RMS over the inliers).
    """
    normal: np.ndarray
    offset: float
    centroid: np.ndarray
    inliers: np.ndarray
    rms: float


@dataclass
class AxisAngle:
    """An axis against a plane normal. Convention: ``angle`` ∈ [0, 90] degrees (sign-folded), ``deviation`` =
    ``min(angle, 90 − angle)`` ∈ [0, 45] degrees, ``pose`` "upright" (angle ≤ 45) or "lying"."""
    angle: float
    deviation: float
    pose: str


def load_labelled_scene(path) -> LabelledScene:
    """Organized PCD with a ``label`` field → ``LabelledScene``.

    Convention: see ``LabelledScene``. Raises ``SourceError`` (missing or unreadable file, no ``label`` field, not an
    organized pinhole cloud).
    """
    from equipose.sources.pcd import read_organized_cloud
    path = pathlib.Path(path)
    if not path.is_file():
        raise SourceError(f"{path} does not exist; pass an organized labelled .pcd (e.g. mOSD learn33.pcd)")
    cloud = read_organized_cloud(path)
    if "label" not in cloud["fields"]:
        raise SourceError(f"{path} has no 'label' field (fields: {sorted(cloud['fields'])} + x, y, z, colour); "
                          "a labelled cloud such as mOSD is needed")
    xyz = cloud["xyz"]
    valid = np.all(np.isfinite(xyz), axis=2) & (np.nan_to_num(xyz[:, :, 2], nan=0.0) > 0)
    label = cloud["fields"]["label"].astype(np.int64)
    return LabelledScene(name=path.stem, xyz=xyz, label=label, valid=valid, rgb=cloud["rgb"], depth=cloud["depth"],
                         K=cloud["K"])


def _check_points(points, min_points: int, what: str) -> np.ndarray:
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InvalidPointsError(f"{what} must be [P, 3] metres, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise InvalidPointsError(f"{what} contain NaN/Inf; drop invalid points first")
    if len(p) < min_points:
        raise TooFewPointsError(f"{what}: {len(p)} points, at least {min_points} needed")
    return p


def fit_plane(points, *, threshold: float = 0.01, iterations: int = 200, seed: int = 0) -> Plane:
    """Robust plane: the SDK's ``equipose.preprocess.fit_plane_ransac`` (RANSAC on 3-point samples, then least squares on
    the inliers, refined twice), wrapped with checks and the fit's centroid, inliers and rms.

    Convention: ``points`` [P, 3] metres (finite, P ≥ 3); ``threshold`` metres (point-to-plane inlier distance).
    Deterministic for a given ``seed``. The normal's sign is arbitrary here (see ``orient_towards_camera``).
    Raises ``InvalidPointsError`` (bad or collinear points), ``TooFewPointsError``.
    """
    from equipose.preprocess import fit_plane_ransac
    p = _check_points(points, 3, "plane points")
    try:
        n, d_ransac, inl = fit_plane_ransac(p, threshold=threshold, iterations=int(iterations), seed=seed)
    except TooFewPointsError:                                                   # P ≥ 3 checked: only collinear
        raise InvalidPointsError("plane points are all collinear; no plane can be fitted") from None
    d = -d_ransac                                                               # n · x + d_ransac = 0 → n · x = d
    if inl.sum() < 3:
        raise TooFewPointsError(f"plane fit kept {int(inl.sum())} inliers within {threshold} m")
    c = p[inl].mean(axis=0)
    rms = float(np.sqrt(np.mean((p[inl] @ n - d) ** 2)))
    return Plane(normal=np.asarray(n, np.float64), offset=float(d), centroid=c, inliers=inl, rms=rms)


def orient_towards_camera(normal, point) -> np.ndarray:
    """Flip a unit ``normal`` [3] so it points from ``point`` [3] (metres, camera frame) towards the camera origin:
    ``normal · (−point) > 0`` ("up" for a table seen from above)."""
    n = np.asarray(normal, np.float64).reshape(3)
    return -n if float(n @ -np.asarray(point, np.float64).reshape(3)) < 0 else n.copy()


def table_plane(scene_or_xyz, label=None, *, threshold: float = 0.01, seed: int = 0) -> Plane:
    """Plane of the table points (labels 1–9, valid), normal oriented towards the camera ("up").

    Convention: a ``LabelledScene``, or ``xyz`` [H, W, 3] metres + ``label`` [H, W]. Raises ``TooFewPointsError``
    when fewer than 100 valid table points exist.
    """
    if isinstance(scene_or_xyz, LabelledScene):
        xyz, label = scene_or_xyz.xyz, scene_or_xyz.label
    else:
        xyz = np.asarray(scene_or_xyz)
    label = np.asarray(label)
    valid = np.all(np.isfinite(xyz), axis=-1) & (np.nan_to_num(xyz[..., 2], nan=0.0) > 0)
    table = valid & (label >= TABLE_LABELS.start) & (label < TABLE_LABELS.stop)
    if table.sum() < 100:
        raise TooFewPointsError(f"only {int(table.sum())} valid table points (labels 1–9); cannot fit the table plane")
    plane = fit_plane(xyz[table].reshape(-1, 3), threshold=threshold, seed=seed)
    n = orient_towards_camera(plane.normal, plane.centroid)
    if n @ plane.normal < 0:
        plane.normal, plane.offset = n, -plane.offset
    return plane


def group_objects(label, valid=None, *, min_points: int = 64) -> tuple:
    """Objects of a label image: ``({object id: [H, W] bool mask}, {object id: valid point count})`` (kept, skipped).

    Convention: ``label`` [H, W] ints (mOSD scheme, object id = label // 10 for label ≥ 20); ``valid`` [H, W] bool
    (None = all valid). Objects with fewer than ``min_points`` valid points are skipped and reported with their count.
    Ids are sorted ascending.
    """
    label = np.asarray(label).astype(np.int64)
    valid = np.ones(label.shape, bool) if valid is None else np.asarray(valid, bool)
    if valid.shape != label.shape:
        raise InvalidPointsError(f"valid mask {valid.shape} does not match the label image {label.shape}")
    ids = np.where(label >= FIRST_OBJECT_LABEL, label // 10, 0)
    kept, skipped = {}, {}
    for oid in sorted(int(i) for i in np.unique(ids[ids > 0])):
        m = (ids == oid) & valid
        n = int(m.sum())
        if n < min_points:
            skipped[oid] = n
        else:
            kept[oid] = m
    return kept, skipped


def axis_table_angle(axis, normal) -> AxisAngle:
    """Angle between an axis and a plane normal, both [3] (any length > 0, any sign), folded: see ``AxisAngle``.
    Raises ``InvalidPointsError`` for zero or non-finite vectors."""
    a = np.asarray(axis, np.float64).reshape(3)
    n = np.asarray(normal, np.float64).reshape(3)
    na, nn = np.linalg.norm(a), np.linalg.norm(n)
    if not (np.isfinite(na) and np.isfinite(nn) and na > 1e-12 and nn > 1e-12):
        raise InvalidPointsError(f"axis {a} and normal {n} must be finite and non-zero")
    cos = min(1.0, abs(float(a @ n)) / (na * nn))
    angle = float(np.degrees(np.arccos(cos)))                                   # [0, 90]
    return AxisAngle(angle=angle, deviation=min(angle, 90.0 - angle), pose="upright" if angle <= 45.0 else "lying")


def principal_axis(points) -> np.ndarray:
    """Unit direction [3] of largest variance of ``points`` [P, 3] (PCA; sign arbitrary). Raises
    ``InvalidPointsError``, ``TooFewPointsError`` (P < 3)."""
    p = _check_points(points, 3, "object points")
    _, _, Vt = np.linalg.svd(p - p.mean(axis=0), full_matrices=False)
    return Vt[0]


def summarize_deviations(deviations) -> dict:
    """Summary of deviations (degrees): ``{n, median, max, within_10, within_20}`` (fractions in [0, 1]; None
    statistics when empty)."""
    d = np.asarray([x for x in deviations if x is not None], np.float64)
    if d.size == 0:
        return {"n": 0, "median": None, "max": None, "within_10": None, "within_20": None}
    return {"n": int(d.size), "median": float(np.median(d)), "max": float(d.max()),
            "within_10": float(np.mean(d <= 10.0)), "within_20": float(np.mean(d <= 20.0))}


def random_axis_fraction_within(deviation_deg: float) -> float:
    """Chance level: probability that an axis drawn uniformly on the sphere has ``deviation ≤ deviation_deg``.

    Convention: degrees; for a uniform axis ``P(a ≤ x) = 1 − cos x`` (a ∈ [0, 90] folded), so for d ≤ 45
    ``P(min(a, 90 − a) ≤ d) = (1 − cos d) + sin d``; 1 for d ≥ 45.
    """
    d = float(np.radians(min(max(float(deviation_deg), 0.0), 45.0)))
    return 1.0 if deviation_deg >= 45.0 else float(1.0 - np.cos(d) + np.sin(d))


def random_axis_summary() -> dict:
    """``summarize_deviations``-shaped chance level of a uniformly random axis (median by bisection, max 45°)."""
    lo, hi = 0.0, 45.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if random_axis_fraction_within(mid) < 0.5 else (lo, mid)
    return {"n": None, "median": 0.5 * (lo + hi), "max": 45.0, "within_10": random_axis_fraction_within(10.0),
            "within_20": random_axis_fraction_within(20.0)}
