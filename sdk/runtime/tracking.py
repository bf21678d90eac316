"""Pose tracking over a frame stream: per-object identities, hypothesis re-use, temporal smoothing, error records.

Convention:
    Input: a frame source (``equipose.sources``; any iterable of ``Frame`` / ``FrameError``). Output: one
    ``TrackRecord`` per frame with ``poses`` (``PoseResult`` with ``object_id``; rotation/translation smoothed, raw
    values in ``raw_rotation`` / ``raw_translation``) and ``errors`` (``FrameError``). A frame that fails (bad depth,
    bad intrinsics, unreadable file) produces an error record and the stream continues; an object whose crop fails
    produces a per-object error and the others are still reported.
    Smoothing is exponential: ``x_s = α · x_prev + (1 − α) · x_new`` for translations (metres) and the same geodesic
    interpolation on SO(3) for rotations (α = ``smoothing``); a jump larger than ``reset_angle_deg`` /
    ``max_jump_m`` resets the track state instead of being smoothed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from equipose.core.errors import ConfigError, EquiposeError
from equipose.core.symmetry import HALF_TURNS
from equipose.runtime.result import FrameError

__all__ = ["TrackRecord", "track", "hold_turn", "hold_azimuth"]


@dataclass
class TrackRecord:
    """Output for one frame: ``poses`` (list of PoseResult) and ``errors`` (list of FrameError)."""
    frame_index: int
    timestamp: float | None = None
    poses: list = field(default_factory=list)
    errors: list = field(default_factory=list)
    frame: object = None

    @property
    def ok(self) -> bool:
        return not self.errors

    def to_dict(self) -> dict:
        return {"frame_index": self.frame_index, "timestamp": self.timestamp,
                "poses": [p.to_dict() for p in self.poses], "errors": [e.to_dict() for e in self.errors]}


def _blend_rotation(R_prev, R_new, alpha: float) -> np.ndarray:
    """Geodesic interpolation: α = 1 keeps R_prev, α = 0 gives R_new."""
    delta = Rotation.from_matrix(R_prev.T @ R_new).as_rotvec()                 # [3] rad, in the previous frame
    return R_prev @ Rotation.from_rotvec((1.0 - alpha) * delta).as_matrix()


def _regions_for(frame, est, boxes, masks, regions, auto, auto_options):
    from equipose.preprocess import auto_masks
    if regions is not None:
        regs = regions(frame) if callable(regions) else regions
        return [r if isinstance(r, dict) else {"box": r, "mask": None} for r in regs]
    if auto:
        ms = auto_masks(frame.depth, frame.K, depth_unit=frame.depth_unit, image_size=frame.image_size,
                        **(auto_options or {}))
        return [{"box": None, "mask": m} for m in ms]
    if boxes is not None or masks is not None:
        n = len(boxes) if boxes is not None else len(masks)
        return [{"box": None if boxes is None else boxes[i], "mask": None if masks is None else masks[i]}
                for i in range(n)]
    raise ConfigError("track needs the objects' regions: boxes, masks, regions (a list or a detector callable) or "
                      "auto=True (tabletop segmentation); a whole-frame crop would take the background for the object")


def hold_turn(result, R_prev: np.ndarray) -> bool:
    """Keep a track's reading of a view that does not settle it: where ``result`` is ``ambiguous`` and reports a
    runner-up half turn (``flip_axis``: its model has a turn classifier), the pose's half turn about category x, y or z
    that lies nearest the track's previous rotation ``R_prev`` [3, 3] replaces the pose where it lies nearer than the
    pose does (``extras["held_turn"]``: that axis; ``raw_rotation`` keeps the frame's own). Returns whether it did."""
    if result.flip_axis is None or not result.ambiguous:
        return False
    closeness = {a: float(np.trace(R_prev.T @ result.rotation @ HALF_TURNS[a])) for a in HALF_TURNS}   # larger =
    axis = max(closeness, key=closeness.get)                                                           # nearer
    if closeness[axis] <= float(np.trace(R_prev.T @ result.rotation)):
        return False
    result.set_pose(result.rotation @ HALF_TURNS[axis], result.translation)
    result.extras["held_turn"] = axis
    return True


def hold_azimuth(result, R_prev: np.ndarray) -> bool:
    """Keep a track's handle direction where a frame does not show the handle: a result whose model has a handle
    (``handle_visible`` False, not None) is turned about its category z axis (the body's symmetry axis: the axis
    stays) to the azimuth nearest the track's previous rotation ``R_prev`` [3, 3] (``extras["held_azimuth"]`` True;
    ``raw_rotation`` keeps the frame's own). Returns whether it did."""
    if result.handle_visible is not False:
        return False
    M = R_prev.T @ result.rotation                                              # [3, 3] trace(M Rz(φ)) is largest at
    phi = float(np.arctan2(M[0, 1] - M[1, 0], M[0, 0] + M[1, 1]))              # this φ (radians)
    c, s = np.cos(phi), np.sin(phi)
    result.set_pose(result.rotation @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), result.translation)
    result.extras["held_azimuth"] = True
    return True


def track(est, source, *, boxes=None, masks=None, regions=None, auto: bool = False, smoothing: float = 0.5,
          reuse_margin: float = 0.05, reset_angle_deg: float = 45.0, max_jump_m: float = 0.1,
          max_frames: int | None = None, auto_options: dict | None = None, keep_frames: bool = False,
          up=None, hold_turns: bool = True):
    """Track object poses over ``source`` with the estimator ``est``. Yields ``TrackRecord`` per frame.

    Regions per frame: ``regions`` (a list, or a callable ``frame -> list`` of boxes or ``{"box", "mask"}`` dicts —
    e.g. a detector), fixed ``boxes`` / ``masks`` (object i keeps id i), ``auto=True`` (tabletop segmentation; ids by
    nearest previous position within ``max_jump_m``), one of them is required.
    ``reuse_margin``: the hypothesis nearest the object's previous rotation is kept when it scores within this relative
    margin of the best one (prevents flip-flopping between near-equal hypotheses). ``smoothing`` α in [0, 1).
    ``up``: the up prior of ``PoseEstimator.predict`` ("plane" or a camera-frame direction [3]) for every frame.
    ``hold_turns``: an ``ambiguous`` result of a model with a turn classifier takes the half turn of its pose that
    lies nearest the track where that is nearer than the pose (``hold_turn``): a half turn the view does not settle
    does not flip the track back and forth; and a mug whose handle the frame does not show keeps the track's handle
    azimuth (``hold_azimuth``).
    """
    if not 0.0 <= smoothing < 1.0:
        raise ConfigError(f"smoothing must be in [0, 1), got {smoothing}")
    if regions is None and not auto and boxes is None and masks is None:
        _regions_for(None, est, boxes, masks, regions, auto, auto_options)     # raises the ConfigError
    state: dict = {}                                                            # id → (R, t) smoothed
    centres: dict = {}                                                          # id → [3] m last observed centre
    next_id = 0
    it = iter(source)
    index = -1
    while True:
        try:
            frame = next(it)
        except StopIteration:
            return
        except EquiposeError as e:                                              # the source itself failed: end
            yield TrackRecord(frame_index=index + 1, errors=[FrameError.from_exception(index + 1, e)])
            return
        index += 1
        if max_frames is not None and index >= max_frames:
            return
        if isinstance(frame, FrameError):
            frame.frame_index = index
            yield TrackRecord(frame_index=index, errors=[frame])
            continue
        rec = TrackRecord(frame_index=index, timestamp=getattr(frame, "timestamp", None),
                          frame=frame if keep_frames else None)
        try:
            regs = _regions_for(frame, est, boxes, masks, regions, auto, auto_options)
            fixed_ids = not auto
            # predicted ids → preferred previous rotations
            if fixed_ids:
                ids = list(range(len(regs)))
                prefer = [state[i][0] if i in state else None for i in ids]
            else:
                ids, prefer = None, None
            outs = est.predict_batch(frame.depth, frame.K, regions=regs, depth_unit=frame.depth_unit,
                                     image_size=frame.image_size, return_errors=True, prefer=prefer,
                                     prefer_margin=reuse_margin, up=up) if regs else []
        except EquiposeError as e:
            rec.errors.append(FrameError.from_exception(index, e))
            yield rec
            continue
        if ids is None:                                                         # auto: associate by position
            ids, taken = [], set()
            for out in outs:
                best, best_d = None, max_jump_m
                if not isinstance(out, FrameError):
                    for oid, c_prev in centres.items():
                        dist = float(np.linalg.norm(out.points_centre - c_prev))
                        if oid not in taken and dist < best_d:
                            best, best_d = oid, dist
                if best is None:                                                # a new object
                    best, next_id = next_id, next_id + 1
                taken.add(best)
                ids.append(best)
        for oid, out in zip(ids, outs):
            if isinstance(out, FrameError):
                out.frame_index, out.object_id = index, oid
                rec.errors.append(out)
                continue
            out.object_id = oid
            out.raw_rotation, out.raw_translation = out.rotation.copy(), out.translation.copy()
            if oid in state and hold_turns:
                hold_azimuth(out, state[oid][0]) or hold_turn(out, state[oid][0])
            if oid in state and smoothing > 0:
                R_prev, t_prev = state[oid]
                angle = float(np.degrees(np.linalg.norm(Rotation.from_matrix(R_prev.T @ out.rotation).as_rotvec())))
                if angle <= reset_angle_deg and np.linalg.norm(out.translation - t_prev) <= max_jump_m:
                    out.set_pose(_blend_rotation(R_prev, out.rotation, smoothing),
                                 smoothing * t_prev + (1.0 - smoothing) * out.translation)
            state[oid] = (out.rotation.copy(), out.translation.copy())
            if out.points_centre is not None:
                centres[oid] = out.points_centre.copy()
            rec.poses.append(out)
        yield rec
