"""The stage pipeline (``equipose.runtime.stage`` / ``pipeline``): a new stage is one registration, stage options and
profiles are validated, and the pipeline a model runs follows its metadata."""
import numpy as np
import pytest

from equipose import PoseEstimator, errors
from equipose.runtime.pipeline import Pipeline
from equipose.runtime.profiles import PROFILES, merge_stage_options
from equipose.runtime.stage import STAGE_ORDER, Stage, register_stage, registered_stages, unregister_stage


@pytest.fixture
def toy_stage():
    """A stage defined in one place: it nudges the pose about the camera's z axis and reports the turn."""

    @register_stage
    class NudgeStage(Stage):
        name = "toy_nudge"
        after = "handle"
        options = {"degrees": 0.0}

        def __init__(self, degrees):
            self.degrees = float(degrees)

        @classmethod
        def build(cls, spec, options, context):
            return cls(options["degrees"]) if options["degrees"] else None

        def describe(self):
            return {"degrees": self.degrees}

        def run(self, state):
            a = np.radians(self.degrees)
            Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
            state.set_pose(Rz @ state.rotation)
            state.extras["toy_nudge_deg"] = self.degrees

    yield NudgeStage
    unregister_stage("toy_nudge")


def test_a_toy_stage_is_one_registration(tiny_model, toy_stage, rng):
    assert STAGE_ORDER.index("toy_nudge") == STAGE_ORDER.index("handle") + 1
    pts = rng.normal(size=(400, 3)) * 0.04 + [0.0, 0.0, 0.7]
    plain = PoseEstimator(tiny_model, threads=1)
    nudged = PoseEstimator(tiny_model, threads=1, stages={"toy_nudge": {"degrees": 30.0}})
    assert "toy_nudge" not in plain.pipeline and {"stage": "toy_nudge", "degrees": 30.0} in nudged.pipeline_info
    r0, r1 = plain.predict_points(pts), nudged.predict_points(pts)
    a = np.radians(30.0)
    Rz = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(r1.rotation, Rz @ r0.rotation, atol=1e-9)
    assert r1.to_dict()["toy_nudge_deg"] == 30.0 and "toy_nudge_deg" not in r0.to_dict()
    assert set(r1.timings["stages"]) == set(nudged.pipeline.stages)


def test_registration_is_checked():
    class Nameless(Stage):
        pass

    with pytest.raises(errors.ConfigError):
        register_stage(Nameless)

    class Orphan(Stage):
        name = "toy_orphan"
        after = "no_such_stage"

    with pytest.raises(errors.ConfigError, match="no_such_stage"):
        register_stage(Orphan)
    assert "toy_orphan" not in registered_stages()


def test_stage_options_are_validated(tiny_model):
    with pytest.raises(errors.ConfigError, match="unknown stage"):
        PoseEstimator(tiny_model, threads=1, stages={"no_such_stage": {}})
    with pytest.raises(errors.ConfigError, match="no option"):
        PoseEstimator(tiny_model, threads=1, stages={"rescore": {"bogus": 1}})
    with pytest.raises(errors.ConfigError, match="unknown profile"):
        PoseEstimator(tiny_model, threads=1, profile="fastest")
    with pytest.raises(errors.ConfigError, match="refine"):
        PoseEstimator(tiny_model, threads=1, refine=-1)


def test_pipeline_follows_options_and_profiles(tiny_model):
    base = PoseEstimator(tiny_model, threads=1, profile="accurate")
    assert [s["stage"] for s in base.pipeline_info] == ["calibrate", "select", "upright", "confidence"]   # no refine calibration
    rescored = PoseEstimator(tiny_model, threads=1, refine=3, refine_iters=4, stages={"rescore": {"points": 64}})
    assert rescored.pipeline.get("rescore").describe() == {"k": 3, "iters": 4, "densify": 0, "points": 64}
    assert rescored.refine == 3 and rescored.refine_iters == 4
    off = PoseEstimator(tiny_model, threads=1, refine=3, stages={"rescore": False})
    assert "rescore" not in off.pipeline and off.refine == 0
    assert PROFILES["fast"]["*"]["rescore"] is False                               # the profile turns it off ...
    fast = PoseEstimator(tiny_model, threads=1, refine=3, profile="fast")        # ... an explicit refine wins
    assert fast.pipeline.get("rescore").k == 3


def test_merge_stage_options_later_layers_win_except_auto():
    merged = merge_stage_options({"rescore": {"k": 5, "iters": 30}, "turn": False},
                                 {"rescore": {"k": "auto", "iters": 10}}, {"turn": True})
    assert merged == {"rescore": {"k": 5, "iters": 10}, "turn": {}}
    assert merge_stage_options({"rescore": False}, {"rescore": {"k": "auto"}}) == {"rescore": False}


def test_pipeline_needs_a_selection(tiny_model):
    est = PoseEstimator(tiny_model, threads=1)
    pipe = Pipeline.build(est.spec, {"select": False, "upright": False})
    x = np.random.default_rng(0).normal(size=(1, est.num_points, 3)).astype(np.float32) * 0.3
    from equipose.preprocess import prepare_points
    prep = prepare_points(x[0] * est.scale + [0, 0, 0.7], est.num_points, est.scale)
    with pytest.raises(errors.ConfigError, match="selected no pose"):
        pipe.run(est.run_model(prep.model_points[None]), 0, prep)


def test_changed_calibration_rebuilds_the_pipeline_and_keeps_its_settings(tiny_model):
    est = PoseEstimator(tiny_model, threads=1, refine=3, refine_iters=4)
    pts = np.random.default_rng(1).normal(size=(400, 3)) * 0.04 + [0.0, 0.0, 0.7]
    R0 = est.predict_points(pts).rotation
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])      # δR: 90° about z
    est.calibration_rotation = turn
    R1 = est.predict_points(pts).rotation                                       # R_cat = R · δRᵀ
    np.testing.assert_allclose(R1, R0 @ turn.T, atol=1e-6)
    assert est.calibration_rotation is turn and (est.refine, est.refine_iters) == (3, 4)


def test_every_profile_entry_names_a_shipped_model_and_builds():
    """Each per-model profile entry is a shipped model whose pipeline accepts its options."""
    from equipose.models import model_names
    shipped = set(model_names())
    for profile, table in PROFILES.items():
        for model, options in table.items():
            if model == "*":
                continue
            assert model in shipped, f"profile {profile!r} names {model!r}, which is not shipped"
            est = PoseEstimator(model, threads=1, profile=profile)
            info = {s["stage"]: s for s in est.pipeline_info}
            for stage, opts in options.items():
                if opts is False:
                    assert stage not in info
                    continue
                for key, value in opts.items():                                 # the option reached the stage
                    if key in info.get(stage, {}):
                        assert info[stage][key] == value, (profile, model, stage, key)
