"""Stage ``confidence`` (metadata ``confidence_calibration``): the result's evidence, and from it the chance that the
pose is right.

Evidence (result extra ``evidence``, every model): how well the chosen pose explains the observed points and how much
of the object was seen —

- ``margin``: the selection's relative score margin to the best hypothesis > 30° away, as the stages left it;
- ``flip_margin``: the same to the best turned (≥ 150°) hypothesis, or the flip stage's margin (1 when none);
- ``residual``: mean distance from each model input point to the posed canonical shape, in shape RMS radii;
- ``outliers``: share of input points farther than ``FAR`` RMS radii from the posed shape (occluders, background);
- ``coverage``: share of the posed shape's points with an input point within ``FAR`` RMS radii (how much was seen);
- ``occlusion``: the share of the box's object cluster that something in front hid (box prompts; else 0);
- ``log_points``: log10 of the crop's point count; ``ambiguous``, ``up_given``: the result's flags (0/1);
- ``handle_seen``, ``handle_share``: mugs: the handle stage's verdict and its handle-zone points / input points;
- ``handle_fit_share``, ``handle_fit_mass``: mugs: how clearly the handle stands out of the body in the fit that
  placed it (its window's share of the excess radius, the excess radius per point; 0 when no handle was seen);
- ``plane_tilt``: (1 − cos θ) / 2 for the angle θ between the pose's category up axis (z) and the normal of the
  support plane the crop found under the object (0 upright, 0.5 lying, 1 upside down; 0 without a plane, e.g. from
  ``predict_points``). The plane is evidence here, not a prior: the pose is not turned to it;
- ``plane_float``, ``plane_sink``: how far the posed shape's lowest point lies above (floats) or below (sinks into)
  that support plane, in shape RMS radii, clipped to 0..``CONTACT_CLIP`` (0 without a plane): an object standing on
  a table touches it;
- ``plane_rest``: |sin 2θ| for the same angle θ: 0 where the pose rests on the plane upright, lying on its side or
  upside down, 1 halfway between (45°, 135°), where nothing stands by itself (0 without a plane);
- ``plane_lying``: sin² θ for the same angle θ: 1 where the pose lies on its side on the plane, 0 upright or upside
  down (0 without a plane): a can lies on a table as often as it stands, a bowl never does;
- ``axis_ratio``: cans under an up prior: the cylinder stage's cost of the best other axis over the pose's axis
  (near 1: the normals barely decide between standing and lying); ``AXIS_RATIO_CLIP`` where the stage did not run;
- ``top_cap``, ``bottom_cap``, ``top_taper``: whether the end the pose calls its top (category +z) looks open or
  closed (``equipose.core.opening.top_closure`` of the input points along the posed axis through the pose's centre):
  the share of points near the axis at the very top (a cup's closed bottom, seen when it stands upside down and is
  posed upright), the same at the posed bottom (seen when it stands upside down and is posed so), and how much the
  body widens towards the posed top;
- ``own_axis_turn``: (1 − cos φ) / 2 for the angle φ between the reported pose's up axis (category z) and that of the
  network's own best hypothesis (the lowest score, before any prior): 0 where the stages kept the network's axis,
  1 where the up prior (or another stage) turned it over — a cup the network saw standing on its opening, held
  upright by ``up="plane"``.

Before the evidence is read, a result whose selection margin is below the calibration's ``runner_up_margin`` is
flagged ``ambiguous``: a pose more than 30° away explains the points about as well, and on the fitting views such
results were wrong at least half the time (``equipose.train.evaluation.confidence.runner_up_margin``; absent or 0: no
such flag). Likewise a result whose ``top_cap`` reaches the calibration's ``closed_top_cap``: the posed top shows a
closed bottom, so the object may stand the other way up, and on the fitting views at least half of such results were
wrong (``equipose.train.evaluation.confidence.closed_top_cap``; absent or 0: no such flag). Under an up prior, a
result whose ``own_axis_turn`` exceeds ``TURNED`` (the network had the object the other way up) and whose ``top_cap``
reaches the calibration's ``turned_top_cap`` is flagged too: at least half of such results on the fitting views were
wrong (``equipose.train.evaluation.confidence.turned_top_cap``). The mirror case: a pose that stands the object on its
opening on the support plane (``plane_tilt`` > 0.5) while the end it calls the bottom, facing up, reads open
(``bottom_cap`` below the calibration's ``open_bottom_cap``) is flagged as well, where at least half of such fitting
results were wrong (``equipose.train.evaluation.confidence.open_bottom_cap``). Each file's thresholds are in its
``confidence_calibration`` (``PoseEstimator(M).metadata``).

With ``confidence_calibration`` in the model file, ``confidence`` = σ(bias + Σ weight·feature): the estimated chance
that the rotation is within 10° of the truth (modulo the symmetry) and the centre within 2 cm, fitted on rendered
views with occluders and sensor noise (``equipose.train.evaluation.confidence``); the selection margin stays in the
evidence. Without it, ``confidence`` stays the margin.

Convention: model units, category frame posed into the centred camera frame of the model input.
"""
from __future__ import annotations

import math

import numpy as np

from equipose.core.logistic import entry_probability
from equipose.core.nearest import nearest_distances
from equipose.runtime.stages.cylinder import AXIS_RATIO_CLIP
from equipose.runtime.stages.flip_risk import flip_margin_reading
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["ConfidenceStage", "FAR", "TURNED", "evidence", "below_runner_up", "closed_top",
           "turned_closed_top", "open_bottom_up"]

FAR = 0.25          # RMS radii: a point farther than this from the other set is unexplained / unseen
CONTACT_CLIP = 2.0  # RMS radii: plane_float / plane_sink saturate here
TURNED = 0.5        # own_axis_turn above this: the network had the axis more than 90° away


def below_runner_up(margin: float, calibration: dict | None) -> bool:
    """Whether a result with selection ``margin`` is flagged ``ambiguous`` under ``calibration`` (the
    ``confidence_calibration`` entry, or None): its margin lies below the entry's ``runner_up_margin``, so a pose more
    than 30° away explains the points about as well. The stage and the calibration's fit both apply this rule."""
    return calibration is not None and margin < calibration.get("runner_up_margin", 0.0)


def turned_closed_top(top_cap: float, own_axis_turn: float, up_given: bool, calibration: dict | None) -> bool:
    """Whether a result is flagged ``ambiguous`` under ``calibration``'s ``turned_top_cap``: an up prior was given,
    the network's own best hypothesis had the object the other way up (``own_axis_turn`` > ``TURNED``) and the posed
    top shows a closed bottom at least that clearly — two readings that the object may stand on its opening. The
    stage and the calibration's fit both apply this rule."""
    t = _flag_level(calibration, "turned_top_cap")
    return t > 0.0 and up_given and own_axis_turn > TURNED and top_cap >= t


def open_bottom_up(plane_tilt: float, bottom_cap: float, calibration: dict | None) -> bool:
    """Whether a result is flagged ``ambiguous`` under ``calibration``'s ``open_bottom_cap``: the pose stands the object
    on its opening on the support plane (``plane_tilt`` > 0.5) while the end it calls the bottom, the one facing up,
    reads open (``bottom_cap`` below that share): an upright cup posed upside down. The stage and the calibration's fit
    both apply this rule."""
    t = _flag_level(calibration, "open_bottom_cap")
    return t > 0.0 and plane_tilt > 0.5 and bottom_cap < t


def closed_top(top_cap: float, calibration: dict | None) -> bool:
    """Whether a result whose evidence reads ``top_cap`` is flagged ``ambiguous`` under ``calibration`` (the
    ``confidence_calibration`` entry, or None): its posed top shows a closed bottom at least as clearly as the
    entry's ``closed_top_cap``. The stage and the calibration's fit both apply this rule."""
    t = _flag_level(calibration, "closed_top_cap")
    return t > 0.0 and top_cap >= t


def _flag_level(calibration: dict | None, key: str) -> float:
    """A flag's threshold in the ``confidence_calibration`` entry (0 when absent: the flag is off)."""
    return 0.0 if calibration is None else float(calibration.get(key, 0.0) or 0.0)


def evidence(state: ObjectState) -> dict:
    """The evidence of a finished state (see the module docstring): {feature name: float}."""
    shape = state.canonical_category if state.canonical_category is not None else state.canonical     # [M, 3]
    shape = np.asarray(shape, np.float64)
    rms = float(np.sqrt(np.mean(np.sum((shape - shape.mean(0)) ** 2, 1)))) or 1.0
    posed = np.ascontiguousarray(shape @ state.rotation.T + state.translation)  # [M, 3] input frame
    x = np.ascontiguousarray(state.points, np.float64)                          # [N, 3]
    d_obs = nearest_distances(posed, x)                                         # [N] input → shape
    d_shape = nearest_distances(x, posed)                                       # [M] shape → input
    crop = state.crop or {}
    n_crop = crop.get("inliers", len(x))
    visible = bool(state.extras.get("handle_visible"))                          # mugs; False without a handle stage
    fit = state.extras.get("handle_fit") if visible else None                  # (share, mass) of the handle fit
    gap = _plane_gap(state, posed, rms)                                         # RMS radii, + above the plane
    cos_up = None if state.support_up is None else float(np.clip(state.rotation[:, 2] @ state.support_up, -1, 1))
    ends = state.closure()                                                   # the posed top: open or closed
    return {
        "margin": float(state.confidence),
        "flip_margin": flip_margin_reading(state),
        "residual": float(d_obs.mean() / rms),
        "outliers": float(np.mean(d_obs > FAR * rms)),
        "coverage": float(np.mean(d_shape < FAR * rms)),
        "occlusion": float(crop.get("occluded_fraction", 0.0) or 0.0),
        "log_points": math.log10(max(int(n_crop), 1)),
        "ambiguous": float(bool(state.ambiguous)),
        "up_given": float(state.up is not None),
        "handle_seen": float(visible),
        "handle_share": float(state.extras.get("handle_points", 0)) / max(len(x), 1),
        "handle_fit_share": fit[0] if fit else 0.0,
        "handle_fit_mass": fit[1] if fit else 0.0,
        "plane_tilt": 0.0 if cos_up is None else float(np.clip(0.5 * (1.0 - cos_up), 0.0, 1.0)),
        "plane_rest": 0.0 if cos_up is None else float(abs(2.0 * cos_up * math.sqrt(max(0.0, 1.0 - cos_up ** 2)))),
        "plane_lying": 0.0 if cos_up is None else float(max(0.0, 1.0 - cos_up ** 2)),
        "plane_float": float(np.clip(gap, 0.0, CONTACT_CLIP)),
        "plane_sink": float(np.clip(-gap, 0.0, CONTACT_CLIP)),
        "axis_ratio": float(state.extras.get("axis_ratio", AXIS_RATIO_CLIP)),
        "top_cap": ends.cap,
        "bottom_cap": ends.bottom,
        "top_taper": ends.taper,
        "own_axis_turn": _own_axis_turn(state),
    }


def _own_axis_turn(state: ObjectState) -> float:
    """(1 − cos φ) / 2 between the pose's category z axis and the network's best hypothesis' (``state.R`` at the
    lowest score; the category frame once calibrated, as the pose)."""
    own = state.R[int(np.argmin(state.scores))]                                 # [3, 3]
    return float(np.clip(0.5 * (1.0 - float(own[:, 2] @ state.rotation[:, 2])), 0.0, 1.0))


def _plane_gap(state: ObjectState, posed: np.ndarray, rms: float) -> float:
    """Height of the posed shape's lowest point above the support plane, in shape RMS radii (0 without a plane).
    ``posed`` [M, 3] model units, centred camera frame; the plane (``support_up``, ``support_offset``) is in metres,
    camera frame: x_camera = scale · x_model + centre."""
    if state.support_up is None or state.support_offset is None:
        return 0.0
    n = state.support_up                                                        # [3] unit, camera frame
    scale = float(state.prep.scale)
    lowest = float((posed @ n).min()) * scale + float(np.asarray(state.prep.centre_m, np.float64) @ n) \
        + state.support_offset                                                  # m above the plane
    return lowest / (rms * scale)


@register_stage
class ConfidenceStage(Stage):
    name = "confidence"
    metadata_key = "confidence_calibration"
    modes = ("category", "instance")
    after = "instance"

    def __init__(self, calibration: dict | None):
        self.calibration = calibration

    @classmethod
    def build(cls, spec, options, context):
        return cls(spec.get(cls.metadata_key))

    def describe(self) -> dict:
        c = self.calibration
        return {"calibrated": c is not None} | ({} if c is None else {"features": list(c["features"])})

    def run(self, state: ObjectState) -> None:
        if state.rotation is None:                                              # no pose chosen: nothing to judge
            return
        c = self.calibration
        if below_runner_up(state.confidence, c):                               # a pose > 30° away fits as well
            state.ambiguous = True
        ev = evidence(state)
        if closed_top(ev["top_cap"], c) or turned_closed_top(ev["top_cap"], ev["own_axis_turn"], state.up is not None, c) \
                or open_bottom_up(ev["plane_tilt"], ev["bottom_cap"], c):      # it may stand the other way up
            state.ambiguous = True
            ev["ambiguous"] = 1.0
        state.extras["evidence"] = {k: round(v, 6) for k, v in ev.items()}
        if c is None:
            return
        state.confidence = entry_probability(c, ev)
