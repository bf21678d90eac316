"""Instance-level mode: known model points (YCB-Video) give their own pose back (camera ← CAD frame)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors


@pytest.fixture(scope="module")
def drill(data_root):
    return np.loadtxt(data_root / "ycb_posecnn" / "models" / "035_power_drill" / "points.xyz")[:, :3]


def _angle(Ra, Rb):
    return np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1)))


@pytest.mark.parametrize("model", ["tiny", "car-partial.int8"])
def test_instance_mode_recovers_a_known_pose(tiny_model, drill, model):
    est = PoseEstimator(tiny_model if model == "tiny" else model, threads=1, model_points=drill)
    rng = np.random.default_rng(3)
    for _ in range(3):
        R = Rotation.random(random_state=rng).as_matrix()
        t = np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), rng.uniform(0.5, 0.9)])
        obs = drill @ R.T + t + rng.normal(scale=0.001, size=drill.shape)      # the whole drill, 1 mm noise
        r = est.predict_points(obs)
        assert _angle(r.rotation, R) < 1.0 and np.linalg.norm(r.translation - t) < 0.005   # 50 ICP iterations
        np.testing.assert_allclose(r.canonical_shape, drill @ r.rotation.T + r.translation)
        assert r.symmetry == "none" and r.symmetry_axis is None


def test_instance_mode_bad_arguments(tiny_model, drill):
    with pytest.raises(errors.InvalidPointsError):
        PoseEstimator(tiny_model, model_points=np.tile(drill[:1], (100, 1)))
    with pytest.raises(errors.ConfigError):
        PoseEstimator(tiny_model, model_points=drill, instance_k=0)
