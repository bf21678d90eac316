"""Instance-level mode: known model points (YCB-Video) give their own pose back (camera ← CAD frame)."""
import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from equipose import PoseEstimator, errors
from equipose.runtime.instance import TEMPLATE_POINTS


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
        posed = drill @ r.rotation.T + r.translation                            # canonical_shape: an FPS subset
        assert len(r.canonical_shape) == min(TEMPLATE_POINTS, len(drill))       # of the model points, posed
        assert cKDTree(posed).query(r.canonical_shape)[0].max() < 1e-9
        assert r.symmetry == "none" and r.symmetry_axis is None


def test_instance_mode_bad_arguments(tiny_model, drill):
    with pytest.raises(errors.InvalidPointsError):
        PoseEstimator(tiny_model, model_points=np.tile(drill[:1], (100, 1)))
    with pytest.raises(errors.ConfigError):
        PoseEstimator(tiny_model, model_points=drill, instance_k=0)


def _open_prism(n: int, seed: int) -> np.ndarray:
    """Points of an open triangular box (three walls + bottom, no lid), metres: a turn of 120° about z fits, upside
    down and a half turn do not."""
    g = np.random.default_rng(seed)
    corners = 0.05 * np.array([[np.cos(a), np.sin(a)] for a in np.radians([90.0, 210.0, 330.0])])   # [3, 2]
    side, u, z = g.integers(0, 3, 3 * n // 4), g.uniform(0, 1, 3 * n // 4), g.uniform(0.0, 0.1, 3 * n // 4)
    wall = corners[side] + u[:, None] * (corners[(side + 1) % 3] - corners[side])
    w = g.dirichlet(np.ones(3), n // 4)                                         # uniform on the bottom triangle
    return np.r_[np.c_[wall, z], np.c_[w @ corners, np.zeros(n // 4)]]


def test_instance_mode_flags_a_turn_the_view_cannot_decide(tiny_model, drill):
    rng = np.random.default_rng(5)
    R = Rotation.random(random_state=rng).as_matrix()
    t = np.array([0.02, -0.03, 0.7])
    est = PoseEstimator(tiny_model, threads=1, model_points=_open_prism(2000, 0))
    obs = _open_prism(2000, 1) @ R.T + t + rng.normal(scale=0.001, size=(2000, 3))   # another sampling of it
    r = est.predict_points(obs)
    assert r.ambiguous and abs(r.rotation[:, 2] @ R[:, 2]) > 0.99               # the axis is known, the turn is not
    est = PoseEstimator(tiny_model, threads=1, model_points=drill)
    r = est.predict_points(drill @ R.T + t + rng.normal(scale=0.001, size=drill.shape))
    assert _angle(r.rotation, R) < 1.0 and not r.ambiguous
