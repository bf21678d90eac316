"""The confidence stage: evidence of a pose, the calibrated logistic model in the metadata, and its fitting tools."""
import json
import math
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors
from equipose.core.metadata import CONFIDENCE_FEATURES, decode_metadata
from equipose.core.model_file import read_metadata_props
from equipose.runtime.stages.confidence import FAR, ConfidenceStage, evidence
from equipose.testing import cup_view_points, posed_state


def _cloud(n=256, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3)) * [0.3, 0.2, 0.4]
    return p


def test_evidence_of_a_perfect_fit_and_of_outliers():
    R, t = Rotation.from_euler("xyz", [20, -35, 60], degrees=True).as_matrix(), np.array([0.1, -0.2, 0.05])
    canon = _cloud()
    x = canon @ R.T + t
    ev = evidence(posed_state(x, R, t, canonical=canon))
    assert set(ev) == set(CONFIDENCE_FEATURES)
    assert ev["residual"] < 1e-3 and ev["outliers"] == 0.0 and ev["coverage"] == 1.0
    assert ev["ambiguous"] == 0.0 and ev["up_given"] == 0.0 and ev["occlusion"] == 0.0
    far = x.copy()
    far[::2] += [3.0, 0.0, 0.0]                                                 # half the points: an occluder
    ev2 = evidence(posed_state(far, R, t, canonical=canon))
    assert ev2["outliers"] == pytest.approx(0.5) and ev2["residual"] > 1.0 and ev2["coverage"] < 0.9
    up = evidence(posed_state(x, R, t, canonical=canon, up=R[:, 2]))
    assert up["up_given"] == 1.0
    assert 0 < FAR < 1


def test_plane_tilt_reads_the_pose_against_the_support_plane():
    R, t = Rotation.from_euler("xyz", [10, -25, 40], degrees=True).as_matrix(), np.zeros(3)
    canon = _cloud(seed=2)
    x = canon @ R.T + t
    none = evidence(posed_state(x, R, t, canonical=canon))
    assert none["plane_tilt"] == 0.0 and none["plane_lying"] == 0.0                    # no plane: no evidence
    readings = []
    for angle in (0.0, 45.0, 90.0, 180.0):                                     # the plane's normal vs the pose's z
        turn = Rotation.from_rotvec(np.radians(angle) * R[:, 0]).as_matrix()
        state = posed_state(x, R, t, canonical=canon)
        state.support_up = turn @ R[:, 2]
        ev = evidence(state)
        readings.append((ev["plane_tilt"], ev["plane_lying"], ev["plane_rest"]))
    tilt, lying, rest = np.array(readings).T
    assert tilt == pytest.approx([0.0, (1 - math.sqrt(0.5)) / 2, 0.5, 1.0], abs=1e-9)
    assert lying == pytest.approx([0.0, 0.5, 1.0, 0.0], abs=1e-9)             # sin²: 1 only on its side
    assert rest == pytest.approx([0.0, 1.0, 0.0, 0.0], abs=1e-6)              # |sin 2θ|: 0 on its side too


def test_plane_contact_reads_how_far_the_posed_shape_floats_above_or_sinks_into_the_plane():
    R, t = Rotation.from_euler("xyz", [5, -15, 30], degrees=True).as_matrix(), np.array([0.05, 0.0, -0.1])
    canon = _cloud(seed=3)
    x = canon @ R.T + t
    rms = float(np.sqrt(np.mean(np.sum((canon - canon.mean(0)) ** 2, 1))))
    n = R[:, 2]                                                                 # the plane under the upright pose
    state = posed_state(x, R, t, canonical=canon)
    assert evidence(state)["plane_float"] == 0.0 and evidence(state)["plane_sink"] == 0.0     # no plane
    lowest = float((x @ n).min() * state.prep.scale + state.prep.centre_m @ n)  # m along n, camera frame
    contact = {}
    for gap in (0.0, 0.3, -0.4, 5.0):                                           # the shape's lowest point, RMS radii
        state.support_up, state.support_offset = n, gap * rms * state.prep.scale - lowest
        ev = evidence(state)
        contact[gap] = (ev["plane_float"], ev["plane_sink"])
    assert contact[0.0] == pytest.approx((0.0, 0.0), abs=1e-9)
    assert contact[0.3] == pytest.approx((0.3, 0.0)) and contact[-0.4] == pytest.approx((0.0, 0.4))
    assert contact[5.0] == pytest.approx((2.0, 0.0))                            # saturates at CONTACT_CLIP


def test_a_frame_prediction_carries_the_support_plane_evidence():
    """On the bundled mug frame (a mug standing on a table) the plane is found for a box prompt with no up prior,
    and the mug model's upright pose reads a small tilt."""
    from equipose.samples import sample_objects, sample_path
    from equipose.sources.folder import FolderSource
    frame = next(iter(FolderSource(sample_path())))
    box = sample_objects()[0]["box"]
    r = PoseEstimator("mug-tabletop").predict(frame.depth, frame.K, box=box, depth_unit=frame.depth_unit, up=None)
    tilt = r.extras["evidence"]["plane_tilt"]
    axis_deg = math.degrees(math.acos(1 - 2 * tilt))
    assert 0.0 < tilt < 0.05 and axis_deg < 20.0


def test_the_handle_fit_enters_the_evidence_only_when_the_handle_is_seen():
    from equipose.samples import sample_objects, sample_path
    from equipose.sources.folder import FolderSource
    frame = next(iter(FolderSource(sample_path())))
    box = sample_objects()[0]["box"]
    r = PoseEstimator("mug-tabletop").predict(frame.depth, frame.K, box=box, depth_unit=frame.depth_unit, up="plane")
    ev = r.extras["evidence"]
    if r.handle_visible:
        share, mass = r.extras["handle_fit"]
        assert ev["handle_fit_share"] == pytest.approx(share, abs=1e-6) and ev["handle_fit_mass"] == pytest.approx(mass, abs=1e-6)
        assert 0.0 < share <= 1.0 and mass > 0.0
    else:
        assert ev["handle_fit_share"] == 0.0 and ev["handle_fit_mass"] == 0.0
    canon = _cloud(seed=3)
    plain = evidence(posed_state(canon, np.eye(3), np.zeros(3), canonical=canon))
    assert plain["handle_fit_share"] == 0.0 and plain["handle_fit_mass"] == 0.0       # no handle stage


def test_stage_applies_the_logistic_model_and_keeps_the_margin():
    R, t = np.eye(3), np.zeros(3)
    canon = _cloud(seed=1)
    cal = {"features": ("margin", "residual"), "weights": np.array([2.0, -10.0]), "bias": -0.5}
    state = posed_state(canon, R, t, canonical=canon)
    state.confidence = 0.4
    ConfidenceStage(cal).run(state)
    ev = state.extras["evidence"]
    assert ev["margin"] == pytest.approx(0.4)
    assert state.confidence == pytest.approx(1 / (1 + math.exp(-(-0.5 + 2.0 * 0.4 - 10.0 * ev["residual"]))))
    plain = posed_state(canon, R, t, canonical=canon)
    plain.confidence = 0.4
    ConfidenceStage(None).run(plain)                                            # uncalibrated: the margin stays
    assert plain.confidence == 0.4 and "evidence" in plain.extras


def test_a_runner_up_within_the_fitted_margin_flags_the_result_ambiguous():
    """A selection margin below the calibration's ``runner_up_margin`` flags the result ``ambiguous``, and the
    evidence reads the flag; a clear margin, or a calibration without the key, leaves the flag as the stages set it."""
    canon = _cloud(seed=2)
    cal = {"features": ("margin", "ambiguous"), "weights": np.array([1.0, -3.0]), "bias": 0.0, "runner_up_margin": 0.02}
    for c, margin, flagged in ((cal, 0.01, True), (cal, 0.04, False), ({**cal, "runner_up_margin": 0.0}, 0.01, False),
                               ({k: v for k, v in cal.items() if k != "runner_up_margin"}, 0.01, False)):
        state = posed_state(canon, np.eye(3), np.zeros(3), canonical=canon)
        state.confidence, state.ambiguous = margin, False
        ConfidenceStage(c).run(state)
        assert state.ambiguous is flagged and state.extras["evidence"]["ambiguous"] == float(flagged)
        assert state.confidence == pytest.approx(1 / (1 + math.exp(-(margin - 3.0 * flagged))))


def test_the_runner_up_margin_is_fitted_where_low_margins_are_coin_tosses():
    from equipose.train.evaluation.confidence import runner_up_margin
    rows = [{"margin": 0.001 * i, "right": i % 2 == 0} for i in range(10)]        # margins < 0.01: half wrong
    rows += [{"margin": 0.02 + 0.003 * i, "right": True} for i in range(10)]     # 0.02–0.047: right
    rows += [{"margin": 0.2 + 0.01 * i, "right": True} for i in range(40)]
    assert runner_up_margin(rows) == 0.02                                      # the widest candidate with ≥ 0.5 wrong
    assert runner_up_margin([{**r, "right": True} for r in rows]) == 0.0


def test_a_closed_posed_top_flags_the_result_ambiguous():
    """A ``top_cap`` at or above the calibration's ``closed_top_cap`` (the posed top shows a closed bottom: the object
    may stand the other way up) flags the result ``ambiguous`` and the evidence reads the flag; below it, or without
    the key, nothing changes."""
    x = cup_view_points(seed=4)
    canon = x - [0.0, 0.0, 0.5]
    flipped = np.diag([1.0, -1.0, -1.0])                                       # posed upside down: its top is closed
    cal = {"features": ("margin", "ambiguous"), "weights": np.array([1.0, -3.0]), "bias": 0.0, "closed_top_cap": 0.1}
    for c, R, flagged in ((cal, flipped, True), (cal, np.eye(3), False), ({**cal, "closed_top_cap": 0.0}, flipped, False),
                          ({k: v for k, v in cal.items() if k != "closed_top_cap"}, flipped, False)):
        state = posed_state(x, R, np.array([0.0, 0.0, 0.5]), canonical=canon @ R.T)
        state.confidence, state.ambiguous = 0.5, False
        ConfidenceStage(c).run(state)
        assert state.ambiguous is flagged and state.extras["evidence"]["ambiguous"] == float(flagged)
        assert state.confidence == pytest.approx(1 / (1 + math.exp(-(0.5 - 3.0 * flagged))))


def test_the_closed_top_share_is_fitted_where_closed_tops_are_mostly_wrong():
    from equipose.train.evaluation.confidence import CLOSED_TOP_WRONG, closed_top_cap, flag_rows
    rows = [{"top_cap": 0.0, "margin": 0.5, "right": i % 3 > 0} for i in range(60)]
    rows += [{"top_cap": 0.06, "margin": 0.5, "right": True} for i in range(10)]        # with them, 45 % wrong
    rows += [{"top_cap": 0.13, "margin": 0.5, "right": i % 10 == 0} for i in range(10)]  # 90 % wrong
    assert CLOSED_TOP_WRONG == 0.5 and closed_top_cap(rows) == 0.08            # the lowest candidate with ≥ 0.5 wrong
    assert closed_top_cap([{**r, "right": True} for r in rows]) == 0.0
    assert closed_top_cap([{"margin": 0.5, "right": False}] * 10) == 0.0       # rows without the evidence
    flagged = flag_rows(rows, {"closed_top_cap": 0.08, "runner_up_margin": 0.0})
    assert [r["ambiguous"] for r in flagged[-10:]] == [1.0] * 10 and "ambiguous" not in flagged[0]


def test_own_axis_turn_reads_how_far_the_stages_turned_the_networks_axis():
    """0 where the pose keeps the axis of the network's best hypothesis, 1 where it was turned over (the up prior
    holding a cup upright that the network saw standing on its opening), 0.5 for a quarter turn."""
    x = cup_view_points(seed=2)
    for turn, expected in ((np.eye(3), 0.0), (np.diag([1.0, -1.0, -1.0]), 1.0),
                           (Rotation.from_euler("x", 90, degrees=True).as_matrix(), 0.5)):
        state = posed_state(x, np.eye(3), np.zeros(3))
        state.set_pose(turn)                                                     # the stages' pose; state.R the network's
        assert evidence(state)["own_axis_turn"] == pytest.approx(expected, abs=1e-9)


def test_a_closed_top_the_network_saw_turned_over_flags_a_result_under_the_up_prior():
    """Under an up prior, a pose whose axis the network had the other way up (own_axis_turn > TURNED) and whose top
    reads closed at or above ``turned_top_cap`` is flagged ``ambiguous``; without the prior, with the network's own
    axis kept, or without the key, it is not."""
    from equipose.runtime.stages.confidence import TURNED, turned_closed_top
    x = cup_view_points(seed=4, upside_down=True)                              # standing on its opening
    cal = {"features": ("margin",), "weights": np.array([1.0]), "bias": 0.0, "turned_top_cap": 0.02}
    flipped = np.diag([1.0, -1.0, -1.0])
    for c, up, own, flagged in ((cal, True, flipped, True), (cal, False, flipped, False), (cal, True, np.eye(3), False),
                                ({**cal, "turned_top_cap": 0.0}, True, flipped, False)):
        state = posed_state(x, own, np.array([0.0, 0.0, 0.5]), up=[0.0, 0.0, 1.0] if up else None)
        state.set_pose(np.eye(3))                                               # held upright
        state.confidence, state.ambiguous = 0.5, False
        ConfidenceStage(c).run(state)
        assert state.ambiguous is flagged, (up, own[2, 2], c)
    assert TURNED == 0.5 and not turned_closed_top(0.5, 1.0, True, None)


def test_the_turned_top_share_is_fitted_where_turned_closed_tops_are_wrong_half_the_time():
    from equipose.train.evaluation.confidence import flag_rows, turned_top_cap
    base = {"margin": 0.5, "up_given": 1.0, "own_axis_turn": 1.0}
    rows = [{**base, "top_cap": 0.025, "right": i % 4 > 0} for i in range(20)]            # 25 % wrong
    rows += [{**base, "top_cap": 0.06, "right": i % 2 == 0} for i in range(10)]          # half wrong
    rows += [{**base, "top_cap": 0.06, "own_axis_turn": 0.0, "right": True} for _ in range(40)]  # network agreed
    rows += [{**base, "top_cap": 0.06, "up_given": 0.0, "right": True} for _ in range(40)]       # no prior
    assert turned_top_cap(rows) == 0.03                                        # the lowest with ≥ half wrong
    assert turned_top_cap([{**r, "right": True} for r in rows]) == 0.0
    flagged = flag_rows(rows, {"turned_top_cap": 0.03})
    assert [r.get("ambiguous") for r in flagged[20:30]] == [1.0] * 10
    assert all("ambiguous" not in r for r in flagged[:20] + flagged[30:])


def test_an_open_end_facing_up_flags_a_pose_that_stands_the_object_on_its_opening():
    """A pose upside down on the support plane (``plane_tilt`` > 0.5) whose end facing up reads open (``bottom_cap``
    below ``open_bottom_cap``) is flagged ``ambiguous``; an upright pose, a closed end facing up, or no key are not."""
    from equipose.runtime.stages.confidence import open_bottom_up
    cal = {"open_bottom_cap": 0.1}
    assert open_bottom_up(1.0, 0.02, cal) and open_bottom_up(0.6, 0.0, cal)
    assert not open_bottom_up(0.0, 0.02, cal) and not open_bottom_up(1.0, 0.15, cal)
    assert not open_bottom_up(1.0, 0.02, {"open_bottom_cap": 0.0}) and not open_bottom_up(1.0, 0.02, None)
    x = cup_view_points(seed=3)                                                 # upright, open top
    flipped = np.diag([1.0, -1.0, -1.0])
    for c, flagged in (({"features": ("margin",), "weights": np.array([1.0]), "bias": 0.0, **cal}, True),
                       ({"features": ("margin",), "weights": np.array([1.0]), "bias": 0.0}, False)):
        state = posed_state(x, flipped, np.array([0.0, 0.0, 0.5]), canonical=(x - [0.0, 0.0, 0.5]) @ flipped)
        state.support_up, state.support_offset = np.array([0.0, 0.0, 1.0]), 1.0      # the table under it, normal +z
        state.confidence, state.ambiguous = 0.5, False
        ConfidenceStage(c).run(state)
        ev = state.extras["evidence"]
        assert ev["plane_tilt"] > 0.5 and ev["bottom_cap"] < 0.1
        assert state.ambiguous is flagged


def test_the_open_bottom_share_is_fitted_where_open_ends_facing_up_are_mostly_wrong():
    from equipose.train.evaluation.confidence import flag_rows, open_bottom_cap
    base = {"margin": 0.5, "plane_tilt": 1.0}
    rows = [{**base, "bottom_cap": 0.11, "right": i % 10 != 0} for i in range(30)]         # 10 % wrong
    rows += [{**base, "bottom_cap": 0.04, "right": i % 10 == 0} for i in range(20)]        # 90 % wrong
    rows += [{**base, "bottom_cap": 0.04, "plane_tilt": 0.0, "right": True} for _ in range(20)]  # posed upright
    assert open_bottom_cap(rows) == 0.1             # the highest with at least half wrong (below 0.12: 21 of 50)
    assert open_bottom_cap([{**r, "right": True} for r in rows]) == 0.0
    flagged = flag_rows(rows, {"open_bottom_cap": 0.1})
    assert [r.get("ambiguous") for r in flagged[30:50]] == [1.0] * 20
    assert all("ambiguous" not in r for r in flagged[:30] + flagged[50:])


def test_calibration_metadata_round_trip_and_errors(tiny_model, tmp_path):
    from equipose.export.onnx_export import update_metadata
    path = tmp_path / "m.onnx"
    shutil.copy(tiny_model, path)
    cal = {"features": ["margin", "coverage"], "weights": [1.5, 2.0], "bias": -3.0, "definition": "test"}
    update_metadata(path, confidence_calibration=cal)
    meta = decode_metadata(read_metadata_props(path))
    assert meta["confidence_calibration"]["features"] == ("margin", "coverage")
    est = PoseEstimator(path, threads=1)
    assert est.pipeline.get("confidence").describe() == {"calibrated": True, "features": ["margin", "coverage"]}
    x = _cloud(300, seed=2) * 0.2 + [0, 0, 0.8]
    r = est.predict_points(x)
    ev = r.to_dict()["evidence"]
    z = -3.0 + 1.5 * ev["margin"] + 2.0 * ev["coverage"]
    assert r.confidence == pytest.approx(1 / (1 + math.exp(-z)), abs=1e-4)
    props = read_metadata_props(path)
    for bad in ({"features": ["nope"], "weights": [1.0], "bias": 0.0},
                {"features": ["margin"], "weights": [1.0, 2.0], "bias": 0.0},
                {"features": ["margin"], "weights": [float("nan")], "bias": 0.0}):
        with pytest.raises(errors.MetadataError, match="confidence_calibration"):
            decode_metadata({**props, "confidence_calibration": json.dumps(bad)})


def test_logistic_fit_auroc_and_reliability():
    from equipose.train.evaluation.confidence import auroc, fit_logistic, predict_logistic, reliability
    rng = np.random.default_rng(0)
    X = rng.normal(size=(2000, 2))
    y = (rng.random(2000) < 1 / (1 + np.exp(-(3 * X[:, 0] - 0.5)))).astype(float)   # the second feature is noise
    w, b = fit_logistic(X, y)
    assert w[0] == pytest.approx(3.0, rel=0.2) and abs(w[1]) < 0.3 and b == pytest.approx(-0.5, abs=0.25)
    p = predict_logistic(X, w, b)
    table, ece = reliability(p, y)
    assert ece < 0.05 and sum(t["n"] for t in table) == 2000
    assert auroc(np.array([0.1, 0.2, 0.8, 0.9]), np.array([0, 0, 1, 1])) == 1.0
    assert auroc(np.array([0.9, 0.8, 0.2, 0.1]), np.array([0, 0, 1, 1])) == 0.0
    assert auroc(np.full(4, 0.5), np.array([0, 1, 0, 1])) == 0.5
    with pytest.raises(errors.ConfigError):
        fit_logistic(X, np.ones(2000))


def test_check_scores_the_stored_confidence_and_the_handle_calls(tmp_path, capsys):
    from equipose.train.evaluation.confidence import main
    row = {"right": True, "rot_err": 2.0, "ambiguous": False, "margin": 0.9, "confidence": 0.9,
           "handle_truth_px": 50, "handle_visible": True}
    rows = [row, {**row, "right": False, "rot_err": 120.0, "confidence": 0.8, "handle_truth_px": 0},   # wrong, sure
            {**row, "right": False, "rot_err": 90.0, "confidence": 0.1, "handle_truth_px": 0, "handle_visible": False},
            {**row, "confidence": 0.7, "handle_truth_px": 10, "handle_visible": False}]
    path = tmp_path / "rows.json"
    path.write_text(json.dumps({"rows": rows}))
    out = tmp_path / "check.json"
    assert main(["--model", "mug.onnx", "--rows", str(path), "--check", "--json", str(out)]) == 0
    summary = json.loads(out.read_text())["summary"]
    assert summary["confident_wrong"] == 1 and summary["auroc"] == pytest.approx(0.75)
    h = summary["handle"]
    assert h["visible"] == 2 and h["precision_1px"] == 0.5 and h["precision_30px"] == 0.5
    assert h["recall_1px"] == 0.5 and (h["hidden"], h["hidden_called_visible"]) == (2, 1)
    assert "confident-wrong 1" in capsys.readouterr().out


def test_every_shipped_model_carries_a_calibrated_confidence():
    from equipose.models import list_models
    for path in list_models():
        meta = decode_metadata(read_metadata_props(path))
        cal = meta["confidence_calibration"]
        assert cal is not None, f"{path.name} has no confidence_calibration (run its release recipe)"
        assert "margin" in cal["features"] and cal["weights"][cal["features"].index("margin")] >= 0
        assert 0.0 <= cal["held_out"]["auroc"] <= 1.0 and cal["held_out"]["n"] > 0
