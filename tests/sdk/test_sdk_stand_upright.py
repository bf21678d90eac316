"""Stage ``stand_upright``: without an up prior, a pose that stands an open container on its opening on the support
plane is stood upright where the end facing up reads open; then its azimuth and centre are refitted."""
import numpy as np
import pytest

from equipose import errors
from equipose.runtime.stage import STAGE_ORDER
from equipose.runtime.stages.rest_side import HALF_TURN_X, RestSideStage, parse_upside_down_rest
from equipose.runtime.stages.stand_upright import StandUprightStage, parse_upright_rest
from equipose.testing import cup_view_points, MetadataSpec, posed_state

UP = np.array([0.0, 0.0, 1.0])


def _state(upside_down: bool, posed_down: bool = True, up=None, plane=True):
    """A cup standing upright (or on its opening) on a table with normal +z, posed on its opening (or upright)."""
    x = cup_view_points(seed=5, upside_down=upside_down)                       # [900, 3], heights 0–1
    canon = cup_view_points(seed=6) - [0.0, 0.0, 0.5]                          # upright, centred on its middle
    state = posed_state(x, HALF_TURN_X if posed_down else np.eye(3), np.array([0.0, 0.0, 0.5]), canonical=canon, up=up)
    if plane:
        state.support_up, state.support_offset = UP.copy(), 0.0
    return state


def test_an_upright_cup_posed_on_its_opening_is_stood_upright_and_refitted():
    state = _state(upside_down=False)
    StandUprightStage(0.1).run(state)
    assert state.extras["rest"] == "upright"
    assert state.rotation[:, 2] @ UP == pytest.approx(1.0, abs=1e-6)          # the opening faces up again
    assert state.extras["upright_reading"]["bottom_cap"] < 0.1
    assert abs(state.translation[2] - 0.5) < 0.1                               # the centre refitted near the body's


@pytest.mark.parametrize("upside_down, posed_down, cap, up, plane", [
    (True, True, 0.1, None, True),        # it does stand on its opening: the end facing up reads closed
    (False, False, 0.1, None, True),      # posed upright already
    (False, True, None, None, True),      # "read": the reading only
    (False, True, 0.1, UP, True),         # an up prior holds the axis: rest_side decides there
    (False, True, 0.1, None, False),      # no support plane under it
])
def test_no_turn_without_the_contradiction(upside_down, posed_down, cap, up, plane):
    state = _state(upside_down, posed_down, up, plane)
    before = state.rotation.copy()
    StandUprightStage(cap).run(state)
    assert "rest" not in state.extras and np.array_equal(state.rotation, before)
    assert ("upright_reading" in state.extras) is (posed_down and up is None and plane)


@pytest.mark.parametrize("stage, parse", [(RestSideStage, parse_upside_down_rest),
                                          (StandUprightStage, parse_upright_rest)])
def test_share_cap_metadata_and_options(stage, parse):
    assert parse('{"cap": 0.12, "fixes": 40}')["cap"] == 0.12 and parse(None) is None
    for bad in ('{"cap": 0}', '{"cap": 1.5}', '{"nope": 1}', "not json"):
        with pytest.raises(errors.MetadataError):
            parse(bad)
    assert stage.build(MetadataSpec(None), {"cap": "auto"}, {}) is None
    assert stage.build(MetadataSpec('{"cap": 0.1}'), {"cap": "auto"}, {}).cap == 0.1
    assert stage.build(MetadataSpec(None), {"cap": "read"}, {}).describe()["cap"] == "read"
    with pytest.raises(errors.ConfigError):
        stage.build(MetadataSpec(None), {"cap": 2.0}, {})


def test_the_turned_centre_sits_at_its_share_of_the_top():
    state = _state(upside_down=False)
    state.support_offset = -1.0                    # posed_state's centre_m is 1 m up z: heights = the points' z
    StandUprightStage(0.1, height=0.5).run(state)
    top = state.extras["upright_reading"]["top_height"]
    assert state.extras["rest"] == "upright" and 0.9 < top < 1.0              # the rim, 95th percentile
    assert state.translation[2] == pytest.approx(0.5 * top)                   # model units = metres here
    refit = _state(upside_down=False)
    refit.support_offset = -1.0
    StandUprightStage(0.1).run(refit)                                          # no height: the refit's centre
    assert np.allclose(refit.rotation, state.rotation)
    assert np.allclose(refit.translation[:2], state.translation[:2]) and refit.translation[2] != state.translation[2]


def test_height_metadata_and_option():
    entry = '{"cap": 0.1, "height": 0.45}'
    assert parse_upright_rest(entry)["height"] == 0.45
    for bad in ('{"cap": 0.1, "height": 0}', '{"cap": 0.1, "height": 1.5}', '{"cap": 0.1, "height": "x"}'):
        with pytest.raises(errors.MetadataError, match="height"):
            parse_upright_rest(bad)
    build = StandUprightStage.build
    assert build(MetadataSpec(entry), {"cap": "auto", "height": "auto"}, {}).describe() == {"cap": 0.1, "height": 0.45}
    assert build(MetadataSpec('{"cap": 0.1}'), {"cap": "auto", "height": "auto"}, {}).height is None
    assert build(MetadataSpec(entry), {"cap": "auto", "height": False}, {}).height is None
    assert build(MetadataSpec(entry), {"cap": 0.05, "height": 0.3}, {}).height == 0.3
    assert build(MetadataSpec(None), {"cap": 0.05, "height": "auto"}, {}).height is None
    assert build(MetadataSpec(entry), {"cap": "read", "height": "auto"}, {}).height is None   # reading only
    for bad in (0.0, 2.0, True, "half"):
        with pytest.raises(errors.ConfigError, match="height"):
            build(MetadataSpec(entry), {"cap": "auto", "height": bad}, {})


def test_place_in_the_pipeline():
    order = STAGE_ORDER
    assert order.index("rest_side") + 1 == order.index("stand_upright") == order.index("rim_axis") - 1
    assert order.index("rim_axis") + 1 == order.index("axis_centre")         # the axis direction, then its line
    assert order.index("axis_centre") + 1 == order.index("handle")          # the handle's body fit reads the axis
