"""The flip stage (``equipose.runtime.flip``): a flipped pose is turned back by a template with a known answer, the
metadata is validated, and a model with templates reports ``flip_margin``."""
import shutil

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors
from equipose.core.geometry import rotation_angle_deg
from equipose.runtime.flip import HALF_TURNS
from equipose.runtime.stages.flip import FlipStage
from equipose.testing import posed_state


def _wedge(rng, n=600):
    """A car-like wedge: long in x, tall at the back (−x), low at the front (+x) — front and back differ."""
    x = rng.uniform(-1, 1, n)
    y = rng.uniform(-0.4, 0.4, n)
    z = rng.uniform(0, 1, n) * (0.6 - 0.25 * x)
    return np.c_[x, y, z - 0.2]


@pytest.mark.parametrize("axis", ["z", "y"])
def test_flip_stage_turns_a_flipped_pose_back(rng, axis):
    template = _wedge(rng)
    R_true = Rotation.from_euler("zyx", [40, 25, -10], degrees=True).as_matrix()
    t = np.array([0.02, -0.01, 0.03])
    obs = _wedge(rng, 400) @ R_true.T + t                                       # another sample of the same shape
    stage = FlipStage(template[None], (axis,), partial=True)
    state = posed_state(obs, R_true @ HALF_TURNS[axis], t)                      # the network's flipped answer
    stage.run(state)
    assert rotation_angle_deg(state.rotation, R_true) < 3.0                     # the fit to another sample
    assert state.extras["flip_margin"] > 0.1 and not state.ambiguous
    R_fixed = state.rotation.copy()
    stage.run(state)                                                            # a right pose stays as it is
    assert rotation_angle_deg(state.rotation, R_fixed) < 1e-4


def test_flip_stage_with_up_only_turns_about_up(rng):
    template = _wedge(rng)
    R_true = Rotation.from_euler("z", 70, degrees=True).as_matrix()
    obs = _wedge(rng, 400) @ R_true.T
    state = posed_state(obs, R_true @ HALF_TURNS["z"], np.zeros(3), up=R_true[:, 2])
    FlipStage(template[None], ("x", "z"), partial=True).run(state)
    assert rotation_angle_deg(state.rotation, R_true) < 3.0
    assert state.rotation[:, 2] @ R_true[:, 2] > np.cos(np.radians(1e-3))      # the axis stays held on up


def test_model_with_flip_templates(tiny_model, tmp_path, rng):
    from equipose.export.flip_templates import add_flip_templates
    from equipose.export.onnx_export import update_metadata
    path = tmp_path / "with_templates.onnx"
    shutil.copy(tiny_model, path)
    clouds = [_wedge(rng, 300) * 0.05 for _ in range(4)]
    tmpl = add_flip_templates(path, tiny_model, clouds, axes=("z",), count=2, points=64, pool=4, source="test")
    assert tmpl.shape == (2, 64, 3)
    est = PoseEstimator(path)
    assert est.metadata["flip_templates"]["axes"] == ["z"]
    r = est.predict_points(clouds[0] + [0.0, 0.0, 0.6])
    assert r.flip_margin is not None and "flip_margin" in r.to_dict()
    assert PoseEstimator(tiny_model).predict_points(clouds[0] + [0.0, 0.0, 0.6]).flip_margin is None
    for bad in ({"points": [[1.0, 2.0]]}, {"points": np.zeros((1, 32, 3)).tolist(), "axes": ["w"]},
                {"axes": ["z"]}):
        with pytest.raises(errors.MetadataError, match="flip_templates"):
            update_metadata(path, flip_templates=bad)


def test_template_consensus_drops_turned_reconstructions(rng):
    from equipose.export.flip_templates import consensus_subset, frame_agreement
    shapes = np.stack([_wedge(rng, 200) for _ in range(8)])                     # [8, 200, 3] one frame
    shapes[[2, 5]] = shapes[[2, 5]] @ HALF_TURNS["z"].T                         # two come out turned front/back
    agree = frame_agreement(shapes, ("z",))
    assert agree[0, 1] and not agree[0, 2] and agree[2, 5]
    keep = consensus_subset(agree, 4)
    assert len(keep) == 4 and not {2, 5} & set(keep.tolist())
    with pytest.raises(errors.InvalidPointsError):
        frame_agreement(shapes[0], ("z",))
