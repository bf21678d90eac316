"""The open-top test (``equipose.core.opening``) and its evidence: an upright cup shows its inside at the top, an
upside-down one its closed bottom."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import errors
from equipose.core.opening import top_closure
from equipose.runtime.stages.confidence import evidence
from equipose.testing import cup_view_points, posed_state


def test_an_open_top_reads_open_and_a_closed_one_closed():
    cap, bottom, taper = top_closure(cup_view_points(), [0.0, 0.0, 1.0], [0.0, 0.0, 0.5])
    assert cap == 0.0 and bottom > 0.1 and taper > 0.2                        # inside floor low, widening upwards
    cap, bottom, taper = top_closure(cup_view_points(upside_down=True), [0.0, 0.0, 1.0], [0.0, 0.0, 0.5])
    assert cap > 0.1 and bottom == 0.0 and taper < -0.2                       # the bottom plate on top, narrowing


def test_the_test_follows_the_axis_and_its_place_not_the_frame():
    R = Rotation.from_euler("xyz", [30, -50, 70], degrees=True).as_matrix()
    shift = np.array([0.4, -0.2, 1.5])
    x = cup_view_points(seed=3)
    ref = top_closure(x, [0.0, 0.0, 1.0], [0.0, 0.0, 0.5])
    moved = top_closure(x @ R.T + shift, R[:, 2] * 3.0, R @ [0.05, -0.03, 0.5] + shift)   # any length, centre off
    assert moved == pytest.approx(ref, abs=1e-9)                              # the circle fit finds the axis again
    down = top_closure(x, [0.0, 0.0, -1.0], [0.0, 0.0, 0.5])                  # the other way round
    assert down.cap == pytest.approx(ref.bottom) and down.bottom == pytest.approx(ref.cap)
    assert down.taper == pytest.approx(-ref.taper)


@pytest.mark.parametrize("points, axis, match", [
    (np.zeros((5, 3)), [0, 0, 1], "N ≥ 10"),
    (np.ones((20, 3)), [0, 0, 0], "non-zero axis"),
    (np.full((20, 3), np.nan), [0, 0, 1], "finite"),
])
def test_bad_input_is_refused(points, axis, match):
    with pytest.raises(errors.InvalidPointsError, match=match):
        top_closure(points, axis, np.zeros(3))


def test_the_evidence_reads_the_posed_top():
    x = cup_view_points(seed=5)
    canon = x - [0.0, 0.0, 0.5]
    up = evidence(posed_state(x, np.eye(3), np.array([0.0, 0.0, 0.5]), canonical=canon))
    flipped = np.diag([1.0, -1.0, -1.0])                                       # the same points, posed upside down
    down = evidence(posed_state(x, flipped, np.array([0.0, 0.0, 0.5]), canonical=canon @ flipped.T))
    assert up["top_cap"] == 0.0 and up["bottom_cap"] > 0.1 and up["top_taper"] > 0.2
    assert down["top_cap"] > 0.1 and down["bottom_cap"] == 0.0 and down["top_taper"] < -0.2


def test_stages_share_one_reading_per_pose():
    x = cup_view_points(seed=5)
    state = posed_state(x, np.eye(3), np.array([0.0, 0.0, 0.5]), canonical=x - [0.0, 0.0, 0.5])
    first = state.closure()
    assert state.closure() is first                                            # the same pose: read once
    assert first == top_closure(state.points, [0.0, 0.0, 1.0], [0.0, 0.0, 0.5])
    flipped = np.diag([1.0, -1.0, -1.0])
    state.set_pose(flipped)                                                    # a new pose: read again
    again = state.closure()
    assert again is not first and again.cap == pytest.approx(first.bottom) and again.bottom == pytest.approx(first.cap)
    state.rotation = np.eye(3)                                                 # set directly, not via set_pose
    assert state.closure() == first
