"""The turn classifier stage (``equipose.runtime.turn_classifier``): numpy scoring matches the torch network it was
trained as, a pose the scorer finds turned is turned back, the metadata is validated, and a model carrying one
reports ``turn_margin``."""
import json
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors
from equipose.core.geometry import rotation_angle_deg
from equipose.core.metadata import encode_turn_classifier
from equipose.runtime.hypotheses import HALF_TURNS
from equipose.runtime.stages.turn import TurnStage, relative_turn
from equipose.runtime.turn_classifier import TurnScorer, score_sets, turned_sets
from equipose.testing import posed_state


def _mean_x_scorer(axes=("z",), margin=0.0, ambiguous_margin=0.05):
    """A hand-set scorer whose logit is the mean canonical x of the set: relu(x), relu(−x) pooled, their difference."""
    point = [(np.array([[1.0, 0, 0], [-1.0, 0, 0]], np.float32), np.zeros(2, np.float32))]
    head = [(np.array([[0, 0, 1.0, -1.0]], np.float32), np.zeros(1, np.float32))]        # mean x+ − mean x−
    meta = decode_metadata_value(encode_turn_classifier(point, head, axes, margin, ambiguous_margin))
    return meta


def decode_metadata_value(text):
    from equipose.core.metadata import _turn_classifier
    return _turn_classifier(text, "test")


def test_turned_sets_are_the_half_turned_canonical_points(rng):
    R = Rotation.random(random_state=1).as_matrix()
    t = rng.normal(size=3)
    x = rng.normal(size=(300, 3))
    sets = turned_sets(x, R, t, axes=("x", "y", "z"), points=300)
    assert sets.shape == (4, 300, 3)
    for k, a in enumerate("xyz", 1):                                              # the set of pose R·H
        np.testing.assert_allclose(sets[k], (x - t) @ (R @ HALF_TURNS[a]), atol=1e-5)


def test_numpy_scores_match_the_torch_network(rng):
    torch = pytest.importorskip("torch")
    from equipose.train.fitting.turn_classifier import PointSetScore
    torch.manual_seed(0)
    net = PointSetScore(width=8).eval()
    sets = rng.normal(size=(5, 4, 64, 3)).astype(np.float32)
    with torch.no_grad():
        expected = net(torch.from_numpy(sets)).numpy()
    point, head = net.layers()
    tc = decode_metadata_value(encode_turn_classifier(point, head, "xyz", 0.0, 1.0))
    np.testing.assert_allclose(score_sets(tc["weights"], sets), expected, rtol=1e-4, atol=1e-5)


@pytest.mark.parametrize("threads", [1, 2])
def test_onnxruntime_scorer_matches_the_numpy_scores(rng, threads):
    point = [(rng.normal(size=(16, 3)).astype(np.float32), rng.normal(size=16).astype(np.float32)),
             (rng.normal(size=(24, 16)).astype(np.float32), rng.normal(size=24).astype(np.float32))]
    head = [(rng.normal(size=(8, 48)).astype(np.float32), rng.normal(size=8).astype(np.float32)),
            (rng.normal(size=(1, 8)).astype(np.float32), rng.normal(size=1).astype(np.float32))]
    weights = {"point": point, "head": head}
    sets = rng.normal(size=(4, 100, 3)).astype(np.float32)
    expected = score_sets(weights, sets)                                        # [4]
    np.testing.assert_allclose(TurnScorer(weights, threads)(sets), expected, rtol=1e-5, atol=1e-5)


def test_turn_stage_turns_back_a_pose_the_scorer_finds_turned(rng):
    stage = TurnStage(_mean_x_scorer(axes=("z",)))
    R_true = Rotation.from_euler("zyx", [30, 20, -10], degrees=True).as_matrix()
    y = rng.normal(size=(256, 3)) + [0.5, 0, 0]                                   # canonical points, mean x > 0
    x = y @ R_true.T
    state = posed_state(x, R_true @ HALF_TURNS["z"], np.zeros(3))                 # the turned answer
    stage.run(state)
    assert rotation_angle_deg(state.rotation, R_true) < 1e-4
    assert state.extras["turn_margin"] > 0.5 and not state.ambiguous
    stage.run(state)                                                              # a right pose stays
    assert rotation_angle_deg(state.rotation, R_true) < 1e-4


def test_turn_stage_keeps_the_pose_within_the_margin_and_flags_a_near_tie(rng):
    stage = TurnStage(_mean_x_scorer(axes=("z",), margin=10.0, ambiguous_margin=0.5))
    y = rng.normal(size=(256, 3)) + [0.1, 0, 0]
    state = posed_state(y, HALF_TURNS["z"], np.zeros(3))
    stage.run(state)
    np.testing.assert_allclose(state.rotation, HALF_TURNS["z"])                   # the turn did not win by 10
    assert state.extras["turn_margin"] < 0 and state.ambiguous


def test_the_runner_up_half_turn_is_reported_relative_to_the_kept_pose(rng):
    """The mean-x scorer on three axes, the pose turned about y: the set turned back about y wins, and the set turned
    about z ties with it (both read the true mean x, as a turn about x keeps x). Relative to the kept (true) pose
    that runner-up is its half turn about x."""
    stage = TurnStage(_mean_x_scorer(axes=("x", "y", "z")))
    R_true = Rotation.from_euler("zyx", [-40, 15, 5], degrees=True).as_matrix()
    y = rng.normal(size=(256, 3)) + [0.5, 0, 0]
    state = posed_state(y @ R_true.T, R_true @ HALF_TURNS["y"], np.zeros(3))     # turned about y
    stage.run(state)
    assert rotation_angle_deg(state.rotation, R_true) < 1e-4                     # turned back
    assert state.extras["flip_axis"] == "x" and abs(state.extras["turn_margin"]) < 1e-5   # the tie
    assert [relative_turn(a, b) for a, b in ((None, "z"), ("x", None), ("x", "y"), ("z", "x"))] == ["z", "x", "z", "y"]


def test_decayed_weights_read_as_zero_and_keep_the_scores(rng):
    """Weights that training decayed to ~1e-38 give subnormal products (~100× slower on x86 without flush-to-zero):
    the decoder zeroes every value below 1e-12 × its tensor's largest, and the scores stay the same to the bit."""
    point = [(rng.normal(size=(16, 3)).astype(np.float32), rng.normal(size=16).astype(np.float32)),
             (rng.normal(size=(24, 16)).astype(np.float32), rng.normal(size=24).astype(np.float32))]
    head = [(rng.normal(size=(1, 48)).astype(np.float32), np.zeros(1, np.float32))]
    point[1][0][:, :5] = np.float32(3e-39)                                      # subnormal
    point[1][0][:, 5:8] = np.float32(1e-30)                                     # normal, but its products are not
    sets = rng.normal(size=(4, 100, 3)).astype(np.float32)
    raw = score_sets({"point": point, "head": head}, sets)
    tc = decode_metadata_value(encode_turn_classifier(point, head, "xyz", 0.0, 1.0))
    W = tc["weights"]["point"][1][0]
    assert not W[:, :8].any() and np.count_nonzero(W) == W.size - 8 * 24         # only the decayed ones are zero
    np.testing.assert_array_equal(score_sets(tc["weights"], sets), raw)
    np.testing.assert_array_equal(TurnScorer(tc["weights"])(sets), TurnScorer({"point": point, "head": head})(sets))


@pytest.mark.parametrize("change, message", [
    (lambda d: d.update(axes=["w"]), "axes"),
    (lambda d: d["head"][0].update(shape=[1, 6]), "malformed|chain"),
    (lambda d: d.update(margin="nan"), "finite"),
    (lambda d: d.pop("point"), "malformed"),
])
def test_malformed_turn_classifier_metadata_is_refused(change, message):
    point = [(np.eye(3, dtype=np.float32)[:2], np.zeros(2, np.float32))]
    head = [(np.ones((1, 4), np.float32), np.zeros(1, np.float32))]
    d = json.loads(encode_turn_classifier(point, head, ["z"], 0.0, 1.0))
    change(d)
    with pytest.raises(errors.MetadataError, match=message):
        decode_metadata_value(json.dumps(d))


def test_model_with_a_turn_classifier(tiny_model, tmp_path, rng):
    from equipose.export.onnx_export import update_metadata
    path = tmp_path / "with_turns.onnx"
    shutil.copy(tiny_model, path)
    point = [(rng.normal(size=(8, 3)).astype(np.float32), np.zeros(8, np.float32))]
    head = [(rng.normal(size=(1, 16)).astype(np.float32), np.zeros(1, np.float32))]
    update_metadata(path, turn_classifier=encode_turn_classifier(point, head, ["x", "y", "z"], 0.0, 0.1))
    est = PoseEstimator(path, threads=1)
    assert est.metadata["turn_classifier"]["axes"] == ["x", "y", "z"]
    pts = rng.normal(size=(400, 3)) * [0.05, 0.03, 0.02] + [0, 0, 0.8]
    res = est.predict_points(pts)
    assert res.turn_margin is not None and res.turn_margin >= 0                   # the kept pose leads its turns
    assert "turn_margin" in res.to_dict() and res.flip_axis in ("x", "y", "z")
    assert rotation_angle_deg(res.flip_rotation, res.rotation) == pytest.approx(180.0, abs=1e-4)
    assert res.to_dict()["flip_rotation"] == np.round(res.flip_rotation, 6).tolist()
    from equipose.train.evaluation.evaluate import predict_onnx                  # what eval's "[either reading]" reads
    *_, flips = predict_onnx(est, [{"points_m": pts}, {"points_m": pts[::-1]}])
    assert flips.shape == (2, 3, 3) and np.allclose(flips[0], res.flip_rotation)
    assert predict_onnx(PoseEstimator(tiny_model, threads=1), [{"points_m": pts}])[-1] is None   # no classifier
    plain = PoseEstimator(tiny_model, threads=1).predict_points(pts)
    turned = rotation_angle_deg(res.rotation, plain.rotation)
    assert turned < 1e-4 or turned > 179.0                                        # itself or a half turn of it
    up = plain.rotation[:, 2]
    res_up = est.predict_points(pts, up=up)                                       # the up prior: turns about up only
    assert res_up.turn_margin is not None


def test_turn_labels_pick_the_turn_closest_to_the_teachers_pose():
    pytest.importorskip("torch")
    from equipose.train.fitting.turn_classifier import turn_labels
    R_t = Rotation.random(6, random_state=3).as_matrix()                           # [6, 3, 3] teacher poses
    small = Rotation.from_rotvec([0.05, -0.03, 0.02]).as_matrix()                  # ≈ 3.5° of own error
    turns = [np.eye(3), HALF_TURNS["x"], HALF_TURNS["y"], HALF_TURNS["z"], HALF_TURNS["y"], np.eye(3)]
    R_s = np.stack([R_t[i] @ turns[i] @ small for i in range(6)])                  # own poses, turned against the teacher
    lab, resid = turn_labels(R_s, R_t, ["x", "y", "z"])
    assert lab.tolist() == [0, 1, 2, 3, 2, 0]
    np.testing.assert_allclose(resid, np.degrees(np.linalg.norm([0.05, -0.03, 0.02])), atol=1e-4)
    lab_z, resid_z = turn_labels(R_s, R_t, ["z"])                                  # only about z
    assert lab_z[[0, 3, 5]].tolist() == [0, 1, 0]
    assert np.all(resid_z[[1, 2, 4]] > 170)                                       # x / y turns: no z turn fixes them


def test_scorer_trained_on_own_poses_learns_which_turn_is_true(rng):
    torch = pytest.importorskip("torch")
    from equipose.train.fitting.turn_classifier import train_scorer
    torch.set_num_threads(1)
    V = 64
    base = rng.normal(size=(400, 3)) * [1.0, 0.4, 0.2]
    base = base[base[:, 0] > -0.3 + 0.6 * rng.random(len(base))][:200]            # a shape thinner towards −x
    R = Rotation.random(V, random_state=5).as_matrix()                            # teacher poses
    X = np.stack([base @ R[i].T for i in range(V)]).astype(np.float32)           # views, centred camera frame
    t = np.zeros((V, 3))
    lab = rng.integers(0, 2, V)                                                   # own poses: right, or turned about z
    R_s = np.stack([R[i] @ (HALF_TURNS["z"] if lab[i] else np.eye(3)) for i in range(V)])
    net = train_scorer(X[:48], R[:48], t[:48], ["z"], steps=300, batch=16, width=16, noise_deg=2.0,
                       student=(R_s[:48], t[:48], lab[:48], np.ones(48, bool)), student_frac=1.0, log=lambda m: None)
    point, head = net.layers()
    tc = decode_metadata_value(encode_turn_classifier(point, head, ["z"], 0.0, 1.0))
    picked = [int(np.argmax(score_sets(tc["weights"], turned_sets(X[i], R_s[i], t[i], ["z"])))) for i in range(48, V)]
    assert np.mean(np.array(picked) == lab[48:]) >= 0.9                           # held-out views


def test_refined_calibration_ignores_category_frame_stages(tiny_model, tmp_path, rng):
    """A file's category-frame stages (here a turn classifier, as an int8 copy inherits from its fp32 file) stay off
    while ``calibrate_onnx_refined`` measures the raw learned-frame poses: the calibration is the plain file's."""
    from equipose.export.onnx_export import update_metadata
    from equipose.train.evaluation.calibration import calibrate_onnx_refined
    path = tmp_path / "with_turns.onnx"
    shutil.copy(tiny_model, path)
    point = [(rng.normal(size=(8, 3)).astype(np.float32), np.zeros(8, np.float32))]
    head = [(rng.normal(size=(1, 16)).astype(np.float32), np.ones(1, np.float32))]    # always turns
    update_metadata(path, turn_classifier=encode_turn_classifier(point, head, ["x", "y", "z"], 0.0, 0.1))
    canon = rng.normal(size=(6, 256, 3)) * [0.4, 0.3, 0.2]
    a = calibrate_onnx_refined(tiny_model, canon, k=2, iters=3)
    b = calibrate_onnx_refined(path, canon, k=2, iters=3)
    np.testing.assert_allclose(a["rotation"], b["rotation"], atol=1e-9)
    np.testing.assert_allclose(a["translation"], b["translation"], atol=1e-9)
