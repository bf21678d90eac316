"""Tracking: the stream continues past bad frames; ids, smoothing and hypothesis re-use."""
import numpy as np

from conftest import K_VGA, sphere_scene, tabletop_scene
from equipose.runtime.result import FrameError
from equipose.sources import Frame


def test_track_continues_past_bad_frames(estimator):
    depth, hit = sphere_scene((0.0, 0.0, 0.8), 0.05)
    good = Frame(depth=depth, K=K_VGA)
    stream = [good,
              Frame(depth=depth.astype(np.uint8), K=K_VGA),                     # cv2.imread without UNCHANGED
              FrameError(0, "SourceError", "file unreadable"),                  # a source-level error record
              Frame(depth=depth, K=np.eye(4)),                                  # broken intrinsics
              good]
    recs = list(estimator.track(stream, boxes=[(250, 170, 140, 140), (900, 900, 10, 10)]))
    assert [r.frame_index for r in recs] == [0, 1, 2, 3, 4]
    assert [len(r.poses) for r in recs] == [1, 0, 0, 0, 1]
    assert recs[1].errors[0].error == "DepthDtypeError"
    assert recs[2].errors[0].error == "SourceError"
    assert recs[3].errors[0].error == "IntrinsicsError"
    # the second box is outside the image: a per-object error, object 0 still reported
    assert [e.object_id for e in recs[0].errors] == [1] and recs[0].errors[0].error == "RegionError"
    assert recs[0].poses[0].object_id == 0 and recs[4].poses[0].object_id == 0
    np.testing.assert_allclose(recs[4].poses[0].rotation, recs[0].poses[0].rotation, atol=1e-6)
    assert recs[0].to_dict()["errors"][0]["object_id"] == 1


def test_smoothing_blends_towards_the_new_pose(estimator):
    d1, _ = sphere_scene((0.0, 0.0, 0.8), 0.05)
    d2, _ = sphere_scene((0.02, 0.0, 0.8), 0.05)
    stream = [Frame(depth=d1, K=K_VGA), Frame(depth=d2, K=K_VGA)]
    box = [(230, 170, 180, 140)]
    raw = list(estimator.track(stream, boxes=box, smoothing=0.0))
    smooth = list(estimator.track(stream, boxes=box, smoothing=0.5, reset_angle_deg=180.0))
    p0, p1 = raw[0].poses[0], raw[1].poses[0]
    s1 = smooth[1].poses[0]
    np.testing.assert_allclose(s1.raw_translation, p1.translation, atol=1e-9)
    if np.linalg.norm(p1.translation - p0.translation) <= 0.1:
        np.testing.assert_allclose(s1.translation, 0.5 * (p0.translation + p1.translation), atol=1e-6)
    np.testing.assert_allclose(s1.rotation @ s1.rotation.T, np.eye(3), atol=1e-9)


def test_auto_tracking_keeps_object_ids(estimator):
    depth, truth = tabletop_scene()
    rng = np.random.default_rng(0)
    stream = []
    for i in range(3):                                                          # the scene pans 4 px per frame
        d = np.roll(depth, 4 * i, axis=1).astype(np.int32)                      # + 2 mm sensor noise
        d[d > 0] += rng.integers(-2, 3, size=int((d > 0).sum()))
        stream.append(Frame(depth=d.astype(np.uint16), K=K_VGA))
    assert not np.array_equal(stream[0].depth, stream[1].depth)
    recs = list(estimator.track(stream, auto=True, smoothing=0.0))
    ids = [sorted(p.object_id for p in r.poses) for r in recs]
    assert ids == [[0, 1]] * 3
    x = [[p.points_centre[0] for p in sorted(r.poses, key=lambda p: p.object_id)] for r in recs]
    assert np.all(np.diff(np.array(x), axis=0) > 0.001)                         # each object follows the pan
    # the random-weight model's translations jump by decimetres between these frames: association must not use them


def test_an_ambiguous_half_turn_keeps_the_tracks_reading():
    """``hold_turn``: an ambiguous result whose runner-up half turn lies nearer the track takes that reading; a
    settled one, one already nearer the track, or one without a runner-up stays as it is."""
    from scipy.spatial.transform import Rotation

    from equipose.core.symmetry import HALF_TURNS
    from equipose.runtime.result import PoseResult
    from equipose.runtime.tracking import hold_turn

    R_track = Rotation.from_euler("zyx", [30, -10, 5], degrees=True).as_matrix()
    nudge = Rotation.from_euler("z", 4, degrees=True).as_matrix()

    def result(R, ambiguous=True, axis="z"):
        shape = np.zeros((4, 3))
        return PoseResult(rotation=R, translation=np.array([0.0, 0.0, 1.0]), score=0.0, confidence=0.5,
                          ambiguous=ambiguous, canonical_shape=shape, canonical_shape_object=shape,
                          hypothesis_index=0, flip_axis=axis)

    turned = result(nudge @ R_track @ HALF_TURNS["z"])                         # the frame read it turned about z
    assert hold_turn(turned, R_track) and turned.extras["held_turn"]
    assert np.allclose(turned.rotation, nudge @ R_track) and np.allclose(turned.canonical_shape[:, 2], 1.0)
    for kept in (result(nudge @ R_track @ HALF_TURNS["z"], ambiguous=False),   # the view settled it
                 result(nudge @ R_track),                                       # already the track's reading
                 result(nudge @ R_track @ HALF_TURNS["z"], axis=None)):         # no runner-up reported
        before = kept.rotation.copy()
        assert not hold_turn(kept, R_track) and np.array_equal(kept.rotation, before)


def test_a_hidden_handle_keeps_the_tracks_azimuth():
    """``hold_azimuth``: a mug result whose handle was not seen turns about its own z (the axis stays) to the azimuth
    nearest the track; one whose handle was seen, or a model without a handle, stays."""
    from scipy.spatial.transform import Rotation

    from equipose.runtime.result import PoseResult
    from equipose.runtime.tracking import hold_azimuth

    R_track = Rotation.from_euler("zyx", [30, -10, 5], degrees=True).as_matrix()
    spin = Rotation.from_euler("z", 130, degrees=True).as_matrix()              # about the object's own z
    tilt = Rotation.from_euler("x", 3, degrees=True).as_matrix()               # the frame's axis 3° off the track

    def result(visible):
        shape = np.zeros((4, 3))
        r = PoseResult(rotation=tilt @ R_track @ spin, translation=np.zeros(3), score=0.0, confidence=0.5,
                       ambiguous=True, canonical_shape=shape, canonical_shape_object=shape, hypothesis_index=0)
        if visible is not None:
            r.set_handle([1.0, 0.0, 0.0], visible, 0)
        return r

    hidden = result(False)
    axis = hidden.rotation[:, 2].copy()
    assert hold_azimuth(hidden, R_track) and hidden.extras["held_azimuth"]
    assert np.allclose(hidden.rotation[:, 2], axis)                            # turned about its own axis only
    def angle(R):
        return float(np.degrees(np.arccos(np.clip((np.trace(R_track.T @ R) - 1.0) / 2.0, -1.0, 1.0))))
    spins = [Rotation.from_euler("z", a, degrees=True).as_matrix() for a in range(0, 360, 2)]
    assert angle(hidden.rotation) <= min(angle(tilt @ R_track @ spin @ z) for z in spins) + 1e-9   # the nearest
    assert angle(hidden.rotation) < 3.0 + 1e-9                                  # azimuth: within the tilt
    assert np.allclose(hidden.handle_direction, hidden.rotation[:, 0])         # the handle follows
    for kept in (result(True), result(None)):
        before = kept.rotation.copy()
        assert not hold_azimuth(kept, R_track) and np.array_equal(kept.rotation, before)
