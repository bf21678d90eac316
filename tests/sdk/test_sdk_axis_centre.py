"""The axis line of a body of revolution from its side normals (``equipose.core.revolution``), and the stage that moves
a pose's symmetry axis onto it (``axis_centre``)."""
import numpy as np
import pytest

from equipose.core.geometry import rotation_between
from equipose.core.normals import point_normals
from equipose.core.revolution import axis_line
from equipose.runtime.stages.axis_centre import AxisCentreStage
from equipose.testing import posed_state


def _side_view(seed=0, radius=0.4, arc=np.pi, noise=0.0, handle=0, centre=(0.3, -0.2, 2.0), axis=(0.2, 1.0, 0.1)):
    """Points of a cylinder's side (axis through ``centre`` along ``axis``) on an ``arc`` facing −z (the camera side),
    their exact outward normals, and ``handle`` extra points of a ring beside it whose normals miss the axis."""
    rng = np.random.default_rng(seed)
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    R = rotation_between(np.array([0.0, 0.0, 1.0]), a)                          # category z → axis
    th = rng.uniform(-arc / 2, arc / 2, 400) - np.pi / 2                        # around the side facing the camera
    z = rng.uniform(-0.5, 0.5, 400)
    local = np.stack([radius * np.cos(th), radius * np.sin(th), z], 1)
    normals = np.stack([np.cos(th), np.sin(th), np.zeros_like(th)], 1)
    if handle:
        phi = rng.uniform(0, 2 * np.pi, handle)                                 # a small ring off the side, in x–z
        ring = np.stack([radius + 0.15 + 0.1 * np.cos(phi), np.full(handle, -0.05), 0.1 * np.sin(phi)], 1)
        local = np.vstack([local, ring])
        normals = np.vstack([normals, np.stack([np.cos(phi), np.zeros(handle), np.sin(phi)], 1) @ np.array(
            [[1, 0, 0], [0, 0.6, 0.8], [0, -0.8, 0.6]])])                     # tilted off any line through the axis
    pts = local @ R.T + np.asarray(centre) + noise * rng.normal(size=local.shape)
    return pts, normals @ R.T, a, np.asarray(centre, float), R


@pytest.mark.parametrize("arc", [np.pi, 0.6 * np.pi])
def test_axis_line_recovers_the_axis_of_a_half_seen_cylinder(arc):
    pts, normals, a, centre, _ = _side_view(arc=arc)
    start = centre + np.array([0.12, 0.0, -0.15])                               # the network's guess, 0.19 off
    line = axis_line(pts, normals, a, start)
    assert line is not None
    off = line.point - centre
    assert np.linalg.norm(off - (off @ a) * a) < 1e-6                           # on the true axis
    assert abs((line.point - start) @ a) < 1e-9                                 # the height along it kept
    assert line.shift == pytest.approx(np.linalg.norm((start - centre) - ((start - centre) @ a) * a), rel=1e-6)


def test_axis_line_ignores_normals_that_miss_the_axis_and_survives_noisy_normals():
    pts, _, a, centre, _ = _side_view(noise=0.004, handle=60)
    normals = point_normals(pts, 12)                                            # estimated, noisy, sign arbitrary
    line = axis_line(pts, normals, a, centre + np.array([0.1, 0.05, 0.1]))
    off = line.point - centre
    assert np.linalg.norm(off - (off @ a) * a) < 0.02                           # 5 % of the radius


def test_axis_line_refuses_a_strip_whose_normals_barely_turn_and_too_few_sides():
    pts, normals, a, centre, _ = _side_view(arc=0.05)
    assert axis_line(pts, normals, a, centre) is None                           # the distance is not settled
    assert axis_line(pts[:10], normals[:10], a, centre) is None                 # too few side normals
    lids = np.tile(a, (100, 1))                                                 # normals along the axis: no side
    assert axis_line(pts[:100], lids, a, centre) is None
    with pytest.raises(ValueError, match=r"\[N, 3\]"):
        axis_line(pts, normals[:5], a, centre)


def _cylinder_state(start, canonical_radius=0.4):
    pts, _, a, centre, R = _side_view(noise=0.002)
    rng = np.random.default_rng(3)
    th, z = rng.uniform(0, 2 * np.pi, 300), rng.uniform(-0.5, 0.5, 300)
    canon = np.stack([canonical_radius * np.cos(th), canonical_radius * np.sin(th), z], 1)
    return posed_state(pts, R, start, canonical=canon, symmetry="continuous:z"), centre, a


def test_the_stage_moves_the_axis_onto_the_side_normals_and_reports_it():
    _, _, _, centre, _ = _side_view()
    state, centre, a = _cylinder_state(centre + np.array([0.1, 0.0, -0.08]))
    R0 = state.rotation.copy()
    AxisCentreStage().run(state)
    off = state.translation - centre
    assert np.linalg.norm(off - (off @ a) * a) < 0.01
    assert np.array_equal(state.rotation, R0)                                   # the rotation is left alone
    assert state.extras["axis_shift_m"] == pytest.approx(0.12, abs=0.02)        # scale 1 m per unit


def test_the_stage_leaves_a_pose_the_fit_would_move_beyond_max_shift():
    _, _, _, centre, _ = _side_view()
    start = centre + np.array([0.5, 0.0, 0.0])                                  # more than half the radius away
    state, _, _ = _cylinder_state(start)
    AxisCentreStage(max_shift=0.5).run(state)
    assert np.array_equal(state.translation, start)
    assert state.extras["axis_shift_m"] is None


def test_the_stage_runs_where_asked_for_partial_bodies_of_revolution_only():
    from equipose import PoseEstimator
    from equipose.core.errors import ConfigError
    on = {"axis_centre": {"enabled": True}}

    def names(model, **kw):
        return [s["stage"] for s in PoseEstimator(model, **kw).pipeline_info]

    for model in ("can-tabletop", "cup-tabletop", "bowl-tabletop", "mug-tabletop"):   # their files hold the entry
        assert "axis_centre" in names(model)
        assert "axis_centre" not in names(model, stages={"axis_centre": {"enabled": False}})
    assert "axis_centre" not in names("bottle-partial")                        # no entry: off unless asked
    assert "axis_centre" in names("bottle-partial", stages=on)
    assert names("mug-tabletop", stages=on).index("axis_centre") < names("mug-tabletop", stages=on).index("handle")
    assert "axis_centre" not in names("car-partial", stages=on)
    assert "axis_centre" not in names("bottle-complete", stages=on)
    with pytest.raises(ConfigError, match="max_shift"):
        PoseEstimator("can-tabletop", stages={"axis_centre": {"enabled": True, "max_shift": 0}})
    with pytest.raises(ConfigError, match="enabled"):
        PoseEstimator("can-tabletop", stages={"axis_centre": {"enabled": "yes"}})


class _Spec:
    """The parts of a ``ModelSpec`` the stage's ``build`` reads."""
    name, partial, symmetry = "test.onnx", True, "continuous:z"

    def __init__(self, entry=None):
        self.entry = entry

    def get(self, key):
        return self.entry if key == "axis_centre" else None


def _built(entry, **options):
    return AxisCentreStage.build(_Spec(entry), {**AxisCentreStage.options, **options}, None)


def test_the_files_entry_switches_the_stage_on_and_gives_its_options():
    from equipose.core.errors import MetadataError
    assert _built(None) is None                                                 # no entry: off
    stage = _built('{"points": 300, "max_shift": 0.5}')
    assert (stage.points, stage.max_shift) == (300, 0.5)
    assert _built("{}").describe() == {"points": "input", "max_shift": 1.0}    # the entry's keys have defaults
    assert _built('{"max_shift": 0.5}', max_shift=1.5, points="cloud").describe() == {"points": "cloud",
                                                                                       "max_shift": 1.5}
    assert _built('{"max_shift": 0.5}', enabled=False) is None
    assert _built(None, enabled=True).describe() == {"points": "input", "max_shift": 1.0}
    for bad in ('{"max_shift": 3}', '{"points": "all"}', "not json", '{"max_shift": true}', "[1]"):
        with pytest.raises(MetadataError, match="axis_centre"):
            _built(bad)
