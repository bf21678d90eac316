"""``equipose predict`` on the bundled sample: text, JSON, overlays; box/mask/auto region options."""
import json

import cv2
import numpy as np

from equipose.cli import main
from equipose.samples import sample_path


def test_predict_box_json_and_overlays(tmp_path, capsys, tiny_model):
    out = tmp_path / "out"
    rc = main(["predict", "--model", str(tiny_model), "--source", str(sample_path()), "--box", "328,233,169,146",
               "--json", "--out", str(out), "--threads", "1"])
    assert rc == 0
    rec = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert rec["frame_index"] == 0 and len(rec["poses"]) == 1 and rec["errors"] == []
    assert 0.5 < rec["poses"][0]["translation_m"][2] < 1.5
    img = cv2.imread(str(out / "000000.png"))
    assert img.shape == (480, 640, 3)
    assert (out / "results.jsonl").read_text().count("\n") == 1


def test_predict_mask_and_auto(tmp_path, capsys, tiny_model):
    mask = np.zeros((480, 640), np.uint8)
    mask[240:370, 340:490] = 255
    cv2.imwrite(str(tmp_path / "m.png"), mask)
    assert main(["predict", "-m", str(tiny_model), "-s", str(sample_path()), "--mask", str(tmp_path / "m.png")]) == 0
    assert main(["predict", "-m", str(tiny_model), "-s", str(sample_path()), "--auto"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("frame 0")]
    assert len(lines) == 2 and all("confidence=" in ln for ln in lines)
    assert main(["predict", "-m", str(tiny_model), "-s", str(sample_path()), "--box", "1,2,3"]) == 2
