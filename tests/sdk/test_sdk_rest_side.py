"""Stage ``rest_side``: under the up prior, an open container is stood on its opening only where the network's own
best hypothesis points down and the upright pose's top reads closed; then its centre is refitted."""
import numpy as np
import pytest

from equipose.runtime.stages.rest_side import HALF_TURN_X, RestSideStage
from equipose.testing import cup_view_points, posed_state

UP = np.array([0.0, 0.0, 1.0])


def _state(upside_down: bool, own_down: bool, up=UP):
    """A cup standing on its opening (or not), posed upright under the prior; the network's own best hypothesis
    points down (or up). The canonical shape is the cup upright, centred."""
    x = cup_view_points(seed=7, upside_down=upside_down)                       # [900, 3], heights 0–1
    canon = cup_view_points(seed=8) - [0.0, 0.0, 0.5]                          # upright, centred on its middle
    state = posed_state(x, np.eye(3), np.array([0.0, 0.0, 0.5]), canonical=canon, up=up)
    state.R = np.stack([HALF_TURN_X if own_down else np.eye(3), np.eye(3)])    # [2, 3, 3]: the first scores best
    state.t, state.scores = np.zeros((2, 3)), np.array([0.1, 0.5])
    return state


def test_a_cup_on_its_opening_is_turned_over_and_refitted():
    state = _state(upside_down=True, own_down=True)
    RestSideStage(0.1).run(state)
    assert state.extras["rest"] == "upside_down"
    assert state.rotation[:, 2] @ UP == pytest.approx(-1.0, abs=1e-6)        # the opening faces the table
    assert state.extras["rest_reading"]["own_up"] == pytest.approx(-1.0) and state.extras["rest_reading"]["top_cap"] > 0.1
    assert abs(state.translation[2] - 0.5) < 0.1                               # the centre refitted near the body's


@pytest.mark.parametrize("upside_down, own_down, cap, up", [
    (False, True, 0.1, UP),           # the top reads open: an upright cup stays upright
    (True, False, 0.1, UP),           # the network's own pose points up: not turned
    (True, True, None, UP),           # "read": readings only
    (True, True, 0.1, None),          # no prior: nothing to do
])
def test_no_turn_without_both_readings(upside_down, own_down, cap, up):
    state = _state(upside_down, own_down, up)
    before = state.rotation.copy()
    RestSideStage(cap).run(state)
    assert "rest" not in state.extras and np.array_equal(state.rotation, before)
    assert ("rest_reading" in state.extras) is (up is not None)
