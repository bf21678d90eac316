"""Stage ``seat``: the centre of a container standing upright on the support plane set to a share of its top's
height above the plane."""
import numpy as np
import pytest

from equipose import errors
from equipose.runtime.stage import STAGE_ORDER
from equipose.runtime.stages.seat import SEAT_DEG, SeatStage, parse_seat
from equipose.testing import cup_view_points, MetadataSpec, posed_state

UP = np.array([0.0, 0.0, 1.0])


def _state(tilt_deg: float = 0.0, plane: bool = True):
    """A cup standing on a table with normal +z (heights = the points' z: posed_state's centre_m is 1 m up z), posed
    upright (tilted about x by ``tilt_deg``) with its centre 0.2 too high."""
    x = cup_view_points(seed=5)                                                # [900, 3], heights 0–1
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    state = posed_state(x, R, np.array([0.05, -0.02, 0.7]), canonical=cup_view_points(seed=6) - [0.0, 0.0, 0.5])
    if plane:
        state.support_up, state.support_offset = UP.copy(), -1.0
    return state


def test_an_upright_pose_is_seated_at_its_share_of_the_top():
    state = _state()
    SeatStage(0.5).run(state)
    reading = state.extras["seat_reading"]
    assert 0.9 < reading["top_height"] < 1.0                                   # the rim, 95th percentile
    assert state.translation[2] == pytest.approx(0.5 * reading["top_height"])  # model units = metres here
    assert np.allclose(state.translation[:2], [0.05, -0.02])                   # moved along the normal only
    assert reading["moved"] == pytest.approx(state.translation[2] - 0.7)


@pytest.mark.parametrize("tilt, plane, height", [
    (SEAT_DEG + 1.0, True, 0.5),          # not standing upright on the plane
    (0.0, False, 0.5),                    # no support plane under it
    (0.0, True, None),                    # "read": the reading only
])
def test_left_where_it_does_not_stand_or_only_reads(tilt, plane, height):
    state = _state(tilt, plane)
    before = state.translation.copy()
    SeatStage(height).run(state)
    assert np.array_equal(state.translation, before)
    assert ("seat_reading" in state.extras) is (plane and tilt < SEAT_DEG)


def test_metadata_and_options():
    assert parse_seat('{"height": 0.47, "height_rows": 400}')["height"] == 0.47 and parse_seat(None) is None
    for bad in ('{"height": 0}', '{"height": 1.5}', '{"nope": 1}', "not json"):
        with pytest.raises(errors.MetadataError):
            parse_seat(bad)
    assert SeatStage.build(MetadataSpec(None), {"height": "auto"}, {}) is None       # no fitted share: off
    assert SeatStage.build(MetadataSpec('{"height": 0.47}'), {"height": "auto"}, {}).height == 0.47
    assert SeatStage.build(MetadataSpec(None), {"height": 0.4}, {}).describe() == {"height": 0.4}
    assert SeatStage.build(MetadataSpec(None), {"height": "read"}, {}).describe() == {"height": "read"}
    for bad in (0.0, 2.0, True, "half"):
        with pytest.raises(errors.ConfigError, match="seat height"):
            SeatStage.build(MetadataSpec(None), {"height": bad}, {})


def test_place_in_the_pipeline():
    assert STAGE_ORDER.index("handle") < STAGE_ORDER.index("seat") < STAGE_ORDER.index("confidence")
