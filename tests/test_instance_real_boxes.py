"""``tools/bench/instance_real.py``: its hand-drawn boxes (``tools/bench/data/ycb_demo_boxes.toml``) name YCB-Video
models and frames of ``ycb_posecnn`` and lie inside the 640 × 480 image; its fit measure."""
import importlib.util
import pathlib
import tomllib
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "ycb_posecnn"


def _tool():
    spec = importlib.util.spec_from_file_location("instance_real", ROOT / "tools" / "bench" / "instance_real.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _objects():
    return tomllib.loads((ROOT / "tools" / "bench" / "data" / "ycb_demo_boxes.toml").read_text())["object"]


def test_boxes_lie_inside_the_frame():
    objects = _objects()
    assert len(objects) == 12 and len({(o["frame"], o["model"]) for o in objects}) == 12   # one box per object
    for o in objects:
        x0, y0, x1, y1 = o["box"]
        assert 0 <= x0 < x1 <= 640 and 0 <= y0 < y1 <= 480, o


@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data/ycb_posecnn not present")
def test_every_box_has_its_frame_and_model_points():
    for o in _objects():
        assert (DATA / "demo_images" / f"{o['frame']}-depth.png").is_file()
        assert (DATA / "models" / o["model"] / "points.xyz").is_file()


def test_crop_fit_counts_the_points_near_the_posed_model():
    from scipy.spatial.transform import Rotation
    fit = _tool().crop_fit
    rng = np.random.default_rng(0)
    model = rng.uniform(-0.05, 0.05, (2000, 3))                                 # m, object frame
    R, t = Rotation.from_euler("xyz", [20, -40, 75], degrees=True).as_matrix(), np.array([0.1, -0.05, 0.8])
    result = SimpleNamespace(rotation=R, translation=t)
    seen = model[:500] @ R.T + t                                                # points of the posed model
    share, rms = fit(result, seen, model)
    assert share == 1.0 and rms < 1e-9
    share, rms = fit(result, np.vstack([seen, seen[:500] + [0.0, 0.0, 0.2]]), model)   # as many 20 cm away
    assert share == pytest.approx(0.5) and rms < 1e-9


def _graspnet_tool():
    spec = importlib.util.spec_from_file_location("instance_graspnet",
                                                  ROOT / "tools" / "bench" / "instance_graspnet.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_graspnet_tool_prompts_from_the_visible_model_and_its_add_s():
    from scipy.spatial.transform import Rotation
    tool = _graspnet_tool()
    K = np.array([[600.0, 0.0, 320.0], [0.0, 600.0, 240.0], [0.0, 0.0, 1.0]])
    depth = np.full((480, 640), 1.0)                                            # a wall 1 m away
    Y = np.array([[0.0, 0.0, 1.002], [0.1, 0.0, 0.9], [0.0, 0.05, 1.5], [0.0, 0.0, -1.0]])
    rows, cols = tool.visible_pixels(Y, depth, K)                               # only the point on the wall
    assert list(rows) == [240] and list(cols) == [320]
    P = np.random.default_rng(0).uniform(-0.05, 0.05, (500, 3))
    R = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    t = np.array([0.0, 0.0, 0.8])
    assert tool.add_s_mm(P, R, t, R, t) == 0.0
    assert 5.0 < tool.add_s_mm(P, R, t, R, t + [0.0, 0.0, 0.01]) <= 10.0      # 1 cm off: at most 10 mm
