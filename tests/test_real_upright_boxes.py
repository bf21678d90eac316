"""The hand-drawn boxes of ``tools/bench/real_upright.py`` (``tools/bench/data/uoc_boxes.toml``): each names a shipped
tabletop model and a frame of ``realsense_tabletop_uoc``, and lies inside the 640 × 480 image."""
import pathlib
import tomllib

import pytest

from equipose.models import model_names

ROOT = pathlib.Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "realsense_tabletop_uoc"


def _objects():
    return tomllib.loads((ROOT / "tools" / "bench" / "data" / "uoc_boxes.toml").read_text())["object"]


def test_boxes_name_shipped_models_and_lie_inside_their_frames():
    objects = _objects()
    assert len(objects) == 35
    models = set(model_names())
    names = set()
    for o in objects:
        assert o["model"] in models
        assert 0 <= o["frame"] <= 8
        x0, y0, x1, y1 = o["box"]
        assert 0 <= x0 < x1 <= 640 and 0 <= y0 < y1 <= 480, o
        assert (o["frame"], o["name"]) not in names                    # the tool keys its rows by frame and name
        names.add((o["frame"], o["name"]))


@pytest.mark.skipif(not DATA.is_dir(), reason="../shared/data/realsense_tabletop_uoc not present")
def test_every_boxed_frame_has_depth_and_colour():
    for frame in {o["frame"] for o in _objects()}:
        assert (DATA / f"{frame:06d}-depth.png").is_file() and (DATA / f"{frame:06d}-color.png").is_file()
