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


def test_box_vs_mask_own_category_table_keeps_each_models_objects(capsys):
    """``tools/bench/box_vs_mask.py``'s own-category table: a model's row counts only the objects assigned its
    category, with the shares beyond 2° and 5 mm."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("box_vs_mask", ROOT / "tools" / "bench" / "box_vs_mask.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    rows = [{"model": "can-tabletop", "scene": "s", "object": 2, "axis_deg": 1.0, "centre_mm": 3.0},
            {"model": "can-tabletop", "scene": "s", "object": 3, "axis_deg": 90.0, "centre_mm": 40.0},
            {"model": "can-tabletop", "scene": "s", "object": 4, "axis_deg": 50.0, "centre_mm": 50.0},   # a bowl
            {"model": "can-tabletop", "scene": "s", "object": 5, "error": "TooFewPointsError"}]
    tool.own_table(rows, ["can-tabletop", "cup-tabletop"], {"s": {"2": "can", "3": "can", "4": "bowl"}})
    out = capsys.readouterr().out.splitlines()
    can = [line.split() for line in out if "can-tabletop" in line]
    assert len(can) == 1 and can[0][1:] == ["2", "45.50", "90.0", "0.50", "21.5", "0.50"]
    assert not any("cup-tabletop" in line for line in out)                        # no cup among the objects
