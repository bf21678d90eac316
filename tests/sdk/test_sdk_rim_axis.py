"""The axis of an open container from the plane of its rim (``equipose.core.rim``), and the stage that turns a pose's
symmetry axis onto it (``rim_axis``)."""
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors
from equipose.core.geometry import rotation_between
from equipose.core.rim import MIN_RIM_POINTS, rim_axis
from equipose.runtime.stages.rim_axis import RimAxisStage, parse_rim_axis
from equipose.testing import posed_state


def _bowl(seed=0, n=1500, radius=0.5, theta_max=1.1, noise=0.003, axis=(0.3, -0.2, 1.0), arc=2 * np.pi):
    """Points of a spherical bowl (the cap of a sphere of ``radius`` below its rim, opening along ``axis``) over an
    ``arc`` of azimuths, with Gaussian ``noise``; returns (points [n, 3], unit axis [3])."""
    rng = np.random.default_rng(seed)
    th = np.arccos(rng.uniform(np.cos(theta_max), 1.0, n))                      # uniform on the cap
    ph = rng.uniform(-arc / 2, arc / 2, n)
    local = radius * np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), -np.cos(th)], 1)
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    pts = local @ rotation_between([0.0, 0.0, 1.0], a).T + [0.1, 0.0, 1.5] + noise * rng.normal(size=local.shape)
    return pts, a


def _tilted(a, degrees, seed=1):
    """``a`` turned by ``degrees`` about a random axis perpendicular to it."""
    p = np.cross(a, np.random.default_rng(seed).normal(size=3))
    return Rotation.from_rotvec(np.radians(degrees) * p / np.linalg.norm(p)).apply(a)


@pytest.mark.parametrize("arc", [2 * np.pi, 1.2 * np.pi])
def test_rim_axis_recovers_the_axis_of_a_bowl_from_a_tilted_start(arc):
    pts, a = _bowl(arc=arc)
    start = _tilted(a, 12.0)
    fit = rim_axis(pts, start)
    assert fit is not None
    err = np.degrees(np.arccos(np.clip(fit.axis @ a, -1, 1)))
    assert err < 1.0 and fit.turn == pytest.approx(12.0, abs=1.0)               # was 12° off, now within 1°
    assert fit.axis @ start > 0 and fit.flat < 0.3                              # the start's sense; a ring band
    flipped = rim_axis(pts, -start)                                             # the band at the other end
    assert flipped is None or flipped.axis @ -start > 0


def test_rim_axis_refuses_too_few_points_and_bad_input():
    pts, a = _bowl(n=MIN_RIM_POINTS)                                            # the band holds fewer
    assert rim_axis(pts, a) is None
    with pytest.raises(errors.InvalidPointsError):
        rim_axis(np.zeros((10, 2)), a)
    with pytest.raises(errors.ConfigError):
        rim_axis(pts, a, band=1.5)


def _bowl_state(start_deg, up=None):
    pts, a = _bowl()
    centre = pts.mean(0)
    x = pts - centre                                                            # model units, centred
    R = rotation_between([0.0, 0.0, 1.0], _tilted(a, start_deg))                # the network's pose, tilted
    state = posed_state(x, R, np.zeros(3), symmetry="continuous:z", up=up)
    return state, a


def test_the_stage_turns_the_axis_onto_the_rim_normal_and_keeps_the_centre():
    state, a = _bowl_state(10.0)
    RimAxisStage(points="input").run(state)
    assert np.degrees(np.arccos(state.rotation[:, 2] @ a)) < 1.0
    assert state.extras["rim_turn_deg"] == pytest.approx(10.0, abs=1.0)
    assert np.allclose(state.translation, 0.0)
    assert np.allclose(state.rotation.T @ state.rotation, np.eye(3), atol=1e-9)


@pytest.mark.parametrize("start_deg, up", [(40.0, None), (10.0, "given")])
def test_the_stage_leaves_a_larger_turn_and_an_up_prior_alone(start_deg, up):
    state, a = _bowl_state(start_deg)
    if up:
        state.up = state.rotation[:, 2].copy()                                  # the prior holds the axis
    before = state.rotation.copy()
    RimAxisStage(max_turn=30.0, points="input").run(state)
    assert np.array_equal(state.rotation, before) and state.extras["rim_turn_deg"] is None


def test_the_entry_and_the_options():
    assert parse_rim_axis(None) is None
    assert parse_rim_axis('{"band": 0.25}') == {"band": 0.25, "max_turn": 30.0, "points": "cloud"}
    for bad in ('{"band": 1.0}', '{"max_turn": 0}', '{"points": "all"}', "[1]", "{"):
        with pytest.raises(errors.MetadataError, match="rim_axis"):
            parse_rim_axis(bad, "m.onnx")
    est = PoseEstimator("bowl-tabletop")
    entry = json.loads(est.metadata["rim_axis"])
    assert est.pipeline.stages["rim_axis"].describe() == entry                 # the shipped file's entry
    order = list(est.pipeline.stages)
    assert order.index("stand_upright") < order.index("rim_axis") < order.index("axis_centre")
    assert "rim_axis" not in PoseEstimator("bowl-tabletop", stages={"rim_axis": {"enabled": False}}).pipeline.stages
    assert "rim_axis" not in PoseEstimator("cup-tabletop").pipeline.stages     # no entry: off
    for bad in ({"band": 0.0}, {"max_turn": 120}, {"enabled": "yes"}):
        with pytest.raises(errors.ConfigError, match="rim_axis"):
            PoseEstimator("bowl-tabletop", stages={"rim_axis": bad})
