"""``PoseResult``: one object's pose, its quality signals and the data to draw it.

Convention:
    ``rotation`` [3, 3] and ``translation`` [3] (metres) map the category frame to the OpenCV camera frame:
    ``x_cam = rotation @ x_obj + translation``. ``quaternion`` is (w, x, y, z) with w ≥ 0. ``canonical_shape`` is the
    model's reconstruction posed in the camera frame [M, 3] metres; ``canonical_shape_object`` the same points in the
    category frame [M, 3] metres (its extent defines the drawn 3D box). Timings are milliseconds.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from equipose.core.frame_error import FrameError  # noqa: F401  (re-exported: its home is the core)
from equipose.core.geometry import matrix_to_quaternion
from equipose.core.symmetry import HALF_TURNS, canonicalise_rotation, parse_symmetry

__all__ = ["PoseResult", "FrameError"]


@dataclass
class PoseResult:
    """Pose of one object.

    Attributes:
        rotation: [3, 3] category frame → camera frame (after calibration).
        translation: [3] metres, camera frame (the category frame's origin).
        score: chamfer score of the chosen hypothesis (model units², lower better).
        confidence: relative margin to the best hypothesis > 30° away (0 = a tie, 1 = no competitor).
        ambiguous: the rotation is not settled by what was seen: a ≈180° flip scores almost as well (front/back or
            upside-down uncertain), or, for a model with a handle, the handle was not seen.
        canonical_shape: [M, 3] metres, camera frame. canonical_shape_object: [M, 3] metres, category frame.
        hypothesis_index: chosen hypothesis (0..59); top_k: best hypotheses (index, score, angle to best).
        symmetry: metadata symmetry string; symmetry_axis: [3] camera-frame unit axis (None if not symmetric);
            rotation_canonical: [3, 3] canonical representative of the symmetry class (== rotation if none).
        category, num_points (points the crop produced), timings (ms: crop, fps, inference, selection, total;
        "stages": {stage: ms} of the selection),
        crop: crop diagnostics, object_id (tracking), random_init (the model has random weights),
        points_centre: [3] metres, camera frame, centroid of the object points the model saw (tracking associates
            objects by it: it does not depend on the chosen hypothesis).
        handle_visible: models with a handle (metadata ``handle``, e.g. ``mug``): whether observed points lie where
            the posed handle is (None for other models); handle_points: how many; handle_direction: [3] camera-frame
            unit handle direction (None for other models). A hidden handle also sets ``ambiguous``.
        up: [3] camera-frame unit "up" the pose was constrained to (``predict(..., up=...)``, the up prior: the
            category's +z lies along it), or None when no up prior was used (or ``up="plane"`` found no plane);
            up_source: "given" (the ``up`` argument) or "rest_facet" (read off a complete cloud's resting face).
        flip_margin: models with front/back templates (metadata ``flip_templates``): relative gap between the
            template fits of the pose and of its half turn about up (small = front/back unsure; sets ``ambiguous``
            below 0.1), else None.
        turn_margin: models with a turn classifier (metadata ``turn_classifier``, ``equipose.runtime.turn_classifier``):
            the pose's lead in logits over its best-scoring half turn (small = unsure; sets ``ambiguous`` below the
            file's ``ambiguous_margin``), else None.
        flip_risk: models with a fitted flip risk (metadata ``flip_risk``, ``equipose.runtime.stages.flip_risk``): the
            estimated chance that the pose is turned by about a half turn (error > 150°); ``ambiguous`` where it
            reaches the file's threshold. Else None.
        flip_axis: models with a turn classifier: the category axis ("x", "y" or "z") of the half turn of the pose
            that scored next best, the likeliest other reading of the view (``flip_rotation``), else None.
        frame_priors: models with metadata ``frame_priors`` (``equipose.runtime.frame_priors``): degrees each step
            turned the pose ({"mirror": 0.8, "footprint": -1.2}; None for a step that left it), else None.
        extras: what further pipeline stages add (``equipose.runtime.stage``), JSON-ready, by field name.
        agreement: with rotated input copies (``PoseEstimator(copies=K)``, K > 1): the fraction of copies whose best
            hypothesis lies within 15° of their consensus (1 = all agree; low = the network is unsure), else None.
    """
    rotation: np.ndarray
    translation: np.ndarray
    score: float
    confidence: float
    ambiguous: bool
    canonical_shape: np.ndarray
    canonical_shape_object: np.ndarray
    hypothesis_index: int
    top_k: list = field(default_factory=list)
    symmetry: str = "none"
    symmetry_axis: np.ndarray | None = None
    rotation_canonical: np.ndarray | None = None
    category: str = ""
    num_points: int = 0
    timings: dict = field(default_factory=dict)
    crop: dict = field(default_factory=dict)
    object_id: int | None = None
    random_init: bool = False
    raw_rotation: np.ndarray | None = None      # before temporal smoothing (tracking only)
    raw_translation: np.ndarray | None = None
    points_centre: np.ndarray | None = None
    handle_visible: bool | None = None
    handle_points: int = 0
    handle_direction: np.ndarray | None = None
    handle_direction_object: np.ndarray | None = None
    up: np.ndarray | None = None
    up_source: str | None = None
    flip_margin: float | None = None
    turn_margin: float | None = None
    flip_risk: float | None = None
    flip_axis: str | None = None
    frame_priors: dict | None = None
    agreement: float | None = None
    extras: dict = field(default_factory=dict)

    def set_pose(self, rotation, translation):
        """Replace the pose (e.g. after smoothing) and update everything derived from it (shape, symmetry axis)."""
        self.rotation = np.asarray(rotation, np.float64).reshape(3, 3)
        self.translation = np.asarray(translation, np.float64).reshape(3)
        self.canonical_shape = self.canonical_shape_object @ self.rotation.T + self.translation
        kind, axis, _ = parse_symmetry(self.symmetry)
        self.symmetry_axis = None if kind == "none" else self.rotation[:, axis].copy()
        self.rotation_canonical = canonicalise_rotation(self.rotation, self.symmetry)
        if self.handle_direction_object is not None:
            self.handle_direction = self.rotation @ self.handle_direction_object

    def set_handle(self, direction_object, visible: bool, count: int):
        """Record the handle check (``equipose.runtime.handle``); a handle that was not seen makes the pose ambiguous."""
        self.handle_direction_object = np.asarray(direction_object, np.float64).reshape(3)
        self.handle_direction = self.rotation @ self.handle_direction_object
        self.handle_visible, self.handle_points = bool(visible), int(count)
        self.ambiguous = bool(self.ambiguous or not visible)

    @property
    def occlusion(self) -> float | None:
        """Box prompts: the share of the object's view that nearer depth clusters inside the box took (occluders in
        front, dropped by the crop: ``crop["occluded_fraction"]``); None for masks and point input."""
        v = self.crop.get("occluded_fraction") if self.crop else None
        return None if v is None else float(v)

    @property
    def flip_rotation(self) -> np.ndarray | None:
        """[3, 3] the pose turned by its half turn about ``flip_axis`` (category → camera; the translation stays):
        what to try where ``ambiguous`` or a high ``flip_risk`` says the pose may be turned. None without one."""
        return None if self.flip_axis is None else self.rotation @ HALF_TURNS[self.flip_axis]

    @property
    def quaternion(self) -> np.ndarray:
        """(w, x, y, z), w ≥ 0, of ``rotation``."""
        return matrix_to_quaternion(self.rotation)

    @property
    def matrix(self) -> np.ndarray:
        """[4, 4] homogeneous transform category → camera (metres)."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.rotation, self.translation
        return T

    def extent(self, lo: float = 2.0, hi: float = 98.0) -> tuple:
        """Robust axis-aligned box of the canonical shape in the category frame: (min [3], max [3]) metres."""
        c = np.asarray(self.canonical_shape_object, np.float64)
        return np.percentile(c, lo, axis=0), np.percentile(c, hi, axis=0)

    def box_corners(self) -> np.ndarray:
        """[8, 3] corners of the oriented 3D box in the camera frame, metres."""
        mn, mx = self.extent()
        corners = np.array([[x, y, z] for x in (mn[0], mx[0]) for y in (mn[1], mx[1]) for z in (mn[2], mx[2])])
        return corners @ self.rotation.T + self.translation                     # [8, 3]

    def to_dict(self, include_shape: bool = False) -> dict:
        """JSON-ready dict (lists and floats). ``include_shape`` adds the canonical shape (camera frame)."""
        d = {
            "object_id": self.object_id,
            "category": self.category,
            "rotation": np.round(self.rotation, 6).tolist(),
            "translation_m": np.round(self.translation, 6).tolist(),
            "quaternion_wxyz": np.round(self.quaternion, 6).tolist(),
            "score": float(self.score),
            "confidence": float(self.confidence),
            "ambiguous": bool(self.ambiguous),
            "hypothesis_index": int(self.hypothesis_index),
            "top_k": self.top_k,
            "symmetry": self.symmetry,
            "symmetry_axis": None if self.symmetry_axis is None else np.round(self.symmetry_axis, 6).tolist(),
            "rotation_canonical": None if self.rotation_canonical is None else np.round(self.rotation_canonical, 6).tolist(),
            "box_extent_m": [np.round(v, 5).tolist() for v in self.extent()],
            "num_points": int(self.num_points),
            "timings_ms": {k: ({n: round(float(x), 3) for n, x in v.items()} if isinstance(v, dict) else
                               round(float(v), 3)) for k, v in self.timings.items()},
            "crop": self.crop,
            "points_centre_m": None if self.points_centre is None else np.round(self.points_centre, 6).tolist(),
            "random_init": bool(self.random_init),
            "up": None if self.up is None else np.round(self.up, 6).tolist(),
            "up_source": self.up_source,
        }
        if self.frame_priors is not None:
            d["frame_priors"] = {k: None if v is None else round(float(v), 4) for k, v in self.frame_priors.items()}
        if self.agreement is not None:
            d["agreement"] = round(float(self.agreement), 4)
        if self.flip_margin is not None:
            d["flip_margin"] = round(float(self.flip_margin), 6)
        if self.turn_margin is not None:
            d["turn_margin"] = round(float(self.turn_margin), 4)
        if self.flip_risk is not None:
            d["flip_risk"] = round(float(self.flip_risk), 4)
        if self.flip_axis is not None:
            d["flip_axis"] = self.flip_axis
            d["flip_rotation"] = np.round(self.flip_rotation, 6).tolist()
        if self.handle_visible is not None:
            d["handle_visible"] = bool(self.handle_visible)
            d["handle_points"] = int(self.handle_points)
            d["handle_direction"] = np.round(self.handle_direction, 6).tolist()
        if self.occlusion is not None:
            d["occlusion"] = round(self.occlusion, 4)
        for k, v in self.extras.items():
            d[k] = np.round(v, 6).tolist() if isinstance(v, np.ndarray) else v
        if include_shape:
            d["canonical_shape_m"] = np.round(self.canonical_shape, 5).tolist()
        return d

    def __repr__(self) -> str:                                                  # arrays stay out of the repr
        return f"PoseResult({self.summary()})"

    def summary(self) -> str:
        """One line: R as a rotation vector (deg), t (m), confidence, flags."""
        from scipy.spatial.transform import Rotation
        rv = Rotation.from_matrix(self.rotation).as_rotvec(degrees=True)
        t = self.translation
        flag = " AMBIGUOUS(flip?)" if self.ambiguous else ""
        if self.handle_visible is not None:
            flag += " handle seen" if self.handle_visible else " handle NOT seen"
        flag += "" if self.up is None else " up-prior"
        oid = "" if self.object_id is None else f"object {self.object_id}: "
        return (f"{oid}{self.category or 'object'} R(rotvec°)=[{rv[0]:7.1f} {rv[1]:7.1f} {rv[2]:7.1f}] "
                f"t(m)=[{t[0]:+.3f} {t[1]:+.3f} {t[2]:+.3f}] confidence={self.confidence:.2f}{flag}")

    def plot(self, image, K, *, axis_length: float | None = None, color=(0, 255, 0), thickness: int = 2,
             label: bool = True) -> np.ndarray:
        """Draw the pose axes (x red, y green, z blue) and the oriented 3D box on a copy of ``image``.

        Convention: ``image`` [H, W, 3] BGR uint8 (a [H, W] depth or grey image is colourised first); ``K`` [3, 3] of
        that image. Returns the new BGR uint8 image.
        """
        from equipose.runtime.overlay import draw_pose
        return draw_pose(image, K, self, axis_length=axis_length, color=color, thickness=thickness, label=label)
