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


def test_predict_one_rgbd_pair_from_files(tmp_path, capsys, tiny_model):
    depth = cv2.imread(str(sample_path() / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
    info = json.loads((sample_path() / "intrinsics.json").read_text())
    K = np.asarray(info["K"])
    cv2.imwrite(str(tmp_path / "d.png"), depth)
    (tmp_path / "K.json").write_text(json.dumps({"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}))
    fxfycxcy = f"{K[0, 0]},{K[1, 1]},{K[0, 2]},{K[1, 2]}"
    box = ["--box", "328,233,169,146", "--threads", "1", "--json"]
    assert main(["predict", "-m", str(tiny_model), "--depth", str(tmp_path / "d.png"), "--intrinsics", fxfycxcy] + box) == 0
    a = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["poses"][0]
    metres = (depth.astype(np.float32) / 1000.0 / 0.0001).astype(np.uint16)   # the same frame at 0.1 mm per unit
    cv2.imwrite(str(tmp_path / "d01.png"), metres)
    assert main(["predict", "-m", str(tiny_model), "--depth", str(tmp_path / "d01.png"), "--intrinsics",
                 str(tmp_path / "K.json"), "--depth-unit", "0.0001"] + box) == 0
    b = json.loads(capsys.readouterr().out.strip().splitlines()[-1])["poses"][0]
    assert a["num_points"] == b["num_points"]                                   # the same crop of the same frame
    np.testing.assert_allclose(a["points_centre_m"], b["points_centre_m"], atol=1e-5)
    np.testing.assert_allclose(a["translation_m"], b["translation_m"], atol=5e-3)   # a random-weights network: the
                                                                                # depth unit's rounding moves its pose
    assert main(["predict", "-m", str(tiny_model), "--depth", str(tmp_path / "d.png")] + box) == 2   # no intrinsics


def test_a_failing_predict_claims_no_output_and_leaves_none(tmp_path, capsys, tiny_model):
    out = tmp_path / "out"
    rc = main(["predict", "-m", str(tiny_model), "-s", str(tmp_path / "missing.pcd"), "--auto", "-o", str(out)])
    assert rc == 2 and not out.exists()
    assert "written" not in capsys.readouterr().err
    rc = main(["predict", "-m", str(tiny_model), "-s", str(sample_path()), "--box", "0,0,20,20", "-o", str(out)])
    assert rc == 1 and not out.exists()                                         # no pose: nothing kept, retry open


def test_overlay_labels_do_not_overlap():
    from equipose.runtime.overlay import place_label
    taken = [[0, 0, 200, 60]]                                                   # the legend
    for _ in range(10):                                                         # ten objects at one spot
        taken.append(place_label((100.0, 100.0), (180, 20), (480, 640), taken))
    for i, a in enumerate(taken):
        assert 0 <= a[0] and a[2] <= 640 and 0 <= a[1] and a[3] <= 480
        for b in taken[i + 1:]:
            assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])


def test_predict_hold_turns_is_the_track_option(monkeypatch, capsys, tiny_model):
    from equipose.runtime import estimator
    seen = []
    real = estimator.PoseEstimator.track

    def spy(self, source, **kw):
        seen.append(kw["hold_turns"])
        return real(self, source, **kw)
    monkeypatch.setattr(estimator.PoseEstimator, "track", spy)
    for extra in ([], ["--hold-turns"]):
        assert main(["predict", "-m", str(tiny_model), "-s", str(sample_path()), "--box", "328,233,169,146",
                     "--threads", "1", *extra]) == 0
    assert seen == [False, True]
