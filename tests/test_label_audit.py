"""``tools/bench/label_audit.py``: the mirror plane of a test cloud, found from the cloud alone."""
import importlib.util
import pathlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

ROOT = pathlib.Path(__file__).resolve().parents[1]


def _audit():
    spec = importlib.util.spec_from_file_location("label_audit", ROOT / "tools" / "bench" / "label_audit.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _mirrored_cloud(seed: int = 0) -> np.ndarray:
    """An asymmetric blob along y made mirror-symmetric about the yz-plane: [2P, 3]."""
    rng = np.random.default_rng(seed)
    half = rng.normal(size=(400, 3)) * [0.15, 0.6, 0.1] + [0.25, 0.0, 0.0]
    half[:200, 1] += 0.4                                                   # no second symmetry (front ≠ back)
    return np.concatenate([half, half * [-1.0, 1.0, 1.0]])


@pytest.mark.parametrize("yaw", [0.0, 7.5, -20.0, 48.0])
def test_the_mirror_plane_turns_with_the_cloud(yaw):
    mod = _audit()
    cloud = Rotation.from_euler("z", yaw, degrees=True).apply(_mirrored_cloud())
    found, at_yaw, at_zero = mod.mirror_yaw(cloud)
    assert abs(found - yaw) <= 0.15
    assert at_yaw <= at_zero + 1e-12
    if abs(yaw) >= 3:
        assert at_yaw < mod.MIRROR_CLEAR * at_zero                         # a clear mirror label


def test_the_frame_base_normal_is_measured_from():
    mod = _audit()
    cloud = Rotation.from_euler("z", 90.0 + 10.0, degrees=True).apply(_mirrored_cloud(1))   # normal along +y, +10°
    found, _, _ = mod.mirror_yaw(cloud, base=90.0)
    assert abs(found - 10.0) <= 0.15
