"""Stage ``flip_risk``: the chance of a half turn from the stages' readings, and ``ambiguous`` from it; its fit."""
import json

import numpy as np
import pytest

from equipose import PoseEstimator, errors
from equipose.core.symmetry import HALF_TURNS
from equipose.runtime.stage import STAGE_ORDER
from equipose.runtime.stages.flip_risk import (TURN_CLIP, FlipRiskStage, flip_features, flip_margin_reading,
                                               flip_risk, parse_flip_risk)
from equipose.testing import MetadataSpec, posed_state

ENTRY = {"features": ["turn_margin", "flip_margin"], "weights": [-1.0, -4.0], "bias": 1.0, "threshold": 0.3}


def _state(turn_margin=None, flip_margin=None, ambiguous=False):
    rng = np.random.default_rng(0)
    state = posed_state(rng.normal(size=(64, 3)), np.eye(3), np.zeros(3))
    if turn_margin is not None:
        state.extras["turn_margin"] = turn_margin
    if flip_margin is not None:
        state.extras["flip_margin"] = flip_margin
    state.ambiguous = ambiguous
    return state


def test_it_runs_after_the_turn_classifier_and_before_the_confidence_reads_the_flag():
    assert STAGE_ORDER.index("turn") < STAGE_ORDER.index("flip_risk") < STAGE_ORDER.index("confidence")


def test_the_risk_sets_ambiguous_in_place_of_the_stages_flags():
    stage = FlipRiskStage(parse_flip_risk(json.dumps(ENTRY)), 0.3)
    clear = _state(turn_margin=3.0, flip_margin=0.5, ambiguous=True)           # a stage flagged it; the risk does not
    stage.run(clear)
    assert clear.extras["flip_risk"] == pytest.approx(1.0 / (1.0 + np.exp(-(1.0 - 3.0 - 2.0))))
    assert clear.ambiguous is False
    unsure = _state(turn_margin=0.1, flip_margin=0.02)                         # no stage flagged it; the risk does
    stage.run(unsure)
    assert unsure.extras["flip_risk"] > 0.3 and unsure.ambiguous is True
    read = _state(turn_margin=0.1, flip_margin=0.02)
    FlipRiskStage(stage.entry, None).run(read)                                 # "read": report only
    assert read.extras["flip_risk"] == unsure.extras["flip_risk"] and read.ambiguous is False
    assert read.extras["flip_readings"] == flip_features(0.1, 0.02, read.confidence, None, False)
    bare = _state(turn_margin=0.1, flip_margin=0.02, ambiguous=True)
    FlipRiskStage(None, None).run(bare)                                         # no model: the readings alone
    assert "flip_risk" not in bare.extras and bare.extras["flip_readings"]["flagged"] == 1.0 and bare.ambiguous


def test_features_clip_and_default_where_a_stage_did_not_run():
    f = flip_features(None, 0.2, 0.05, None, True)
    assert f == {"turn_margin": TURN_CLIP, "flip_margin": 0.2, "margin": 0.05, "agreement": 1.0, "flagged": 1.0}
    assert flip_features(-50.0, 0.0, 0.0, 0.5, False)["turn_margin"] == -TURN_CLIP
    assert flip_risk(f, parse_flip_risk(ENTRY)) == pytest.approx(1.0 / (1.0 + np.exp(-(1.0 - TURN_CLIP - 0.8))))
    state = _state()
    assert flip_margin_reading(state) == 1.0                                    # one hypothesis: no turned rival
    state.selection.flip_margin = 0.3
    assert flip_margin_reading(state) == 0.3                                    # the selection's
    state.extras["flip_margin"] = 1.7                                           # the templates' margin wins, clipped
    assert flip_margin_reading(state) == 1.0


def test_metadata_and_options():
    assert parse_flip_risk(None) is None
    assert parse_flip_risk(json.dumps(ENTRY))["threshold"] == 0.3
    for bad in ({**ENTRY, "features": ["nope", "flip_margin"]}, {**ENTRY, "weights": [1.0]},
                {**ENTRY, "threshold": 1.0}, {**ENTRY, "bias": float("nan")}, {"features": []}):
        with pytest.raises(errors.MetadataError, match="flip_risk"):
            parse_flip_risk(json.dumps(bad))
    assert FlipRiskStage.build(MetadataSpec(None), {"threshold": "auto"}, {}) is None      # no fitted model: off
    assert FlipRiskStage.build(MetadataSpec(None), {"threshold": "read"}, {}).describe() == \
        {"features": [], "threshold": "read"}                                   # what the fit runs
    with pytest.raises(errors.ConfigError, match="no flip_risk model"):
        FlipRiskStage.build(MetadataSpec(None), {"threshold": 0.2}, {})
    spec = MetadataSpec(json.dumps(ENTRY))
    assert FlipRiskStage.build(spec, {"threshold": "auto"}, {}).threshold == 0.3
    assert FlipRiskStage.build(spec, {"threshold": 0.15}, {}).describe()["threshold"] == 0.15
    assert FlipRiskStage.build(spec, {"threshold": "read"}, {}).describe()["threshold"] == "read"
    for bad in (0.0, 1.0, True, "half"):
        with pytest.raises(errors.ConfigError, match="flip_risk threshold"):
            FlipRiskStage.build(spec, {"threshold": bad}, {})


def test_the_shipped_car_partial_reports_its_flip_risk():
    est = PoseEstimator("car-partial")
    assert "flip_risk" in est.pipeline.stages
    rng = np.random.default_rng(3)
    r = est.predict_points(rng.normal(size=(800, 3)) * [0.9, 0.4, 0.3] + [0.0, 0.0, 2.0])
    assert 0.0 <= r.flip_risk <= 1.0 and r.to_dict()["flip_risk"] == round(r.flip_risk, 4)
    turn = r.rotation.T @ r.flip_rotation                                       # the runner-up: a half turn
    assert np.allclose(turn, HALF_TURNS[r.flip_axis], atol=1e-9)
    assert r.ambiguous == (r.flip_risk >= est.pipeline.stages["flip_risk"].threshold) or \
        r.extras["evidence"]["margin"] < est.metadata["confidence_calibration"].get("runner_up_margin", 0.0)
    off = PoseEstimator("car-partial", stages={"flip_risk": False})
    assert off.predict_points(rng.normal(size=(800, 3)) + [0.0, 0.0, 2.0]).flip_risk is None


def _rows(n_shapes=40, views=10, seed=0):
    """Synthetic fit rows: a flip is likelier the smaller the turn margin."""
    rng = np.random.default_rng(seed)
    rows = []
    for s in range(n_shapes):
        for v in range(views):
            turn = rng.normal(1.5, 1.5)
            flipped = bool(rng.random() < 1.0 / (1.0 + np.exp(2.0 * turn - 1.0)))
            rows.append({"shape": s, "view": v, "rot_err": 180.0 if flipped else 3.0, "flipped": flipped,
                         **flip_features(turn, float(rng.uniform(0, 1)), float(rng.uniform(0, 0.3)), None, False)})
    return rows


def test_the_fit_flags_its_share_and_ranks_flips_above_the_rest():
    from equipose.train.evaluation.flip_risk import fit
    rows = _rows()
    entry, summary, stages = fit(rows, flag_share=0.25)
    parsed = parse_flip_risk(json.dumps(entry))                               # what the stage reads back
    assert "turn_margin" in parsed["features"] and "agreement" not in parsed["features"]   # constant: dropped
    assert parsed["weights"][list(parsed["features"]).index("turn_margin")] < 0
    risk = np.array([flip_risk(r, parsed) for r in rows])
    assert np.mean(risk >= parsed["threshold"]) == pytest.approx(0.25, abs=0.01)
    assert summary["auroc"] > 0.75 and summary["flagged_flip_rate"] > summary["unflagged_flip_rate"]
    assert stages["flagged_share"] == 0.0                                       # no stage flagged a synthetic row
    with pytest.raises(errors.ConfigError, match="flipped and unflipped"):
        fit([dict(r, flipped=False) for r in rows])
    with pytest.raises(errors.ConfigError, match="flag-share"):
        fit(rows, flag_share=1.0)


def test_the_overlay_label_shows_the_flip_risk():
    from types import SimpleNamespace

    from equipose.runtime.overlay import pose_label
    r = SimpleNamespace(category="car", confidence=0.61, ambiguous=True, object_id=None, flip_risk=0.38)
    assert pose_label(r) == "car conf 0.61 turned? 0.38 AMBIGUOUS (may be turned)"
    plain = SimpleNamespace(category="mug", confidence=0.5, ambiguous=False, object_id=3)
    assert pose_label(plain) == "#3 mug conf 0.50"
