"""End to end through the CLI: tiny train → resume → calibrate → eval (complete and partial), and 2-process DDP."""
import json
import os
import subprocess
import sys

import pytest

torch = pytest.importorskip("torch")

from equipose.cli import main  # noqa: E402
from equipose.train.fitting.checkpoint import load_checkpoint  # noqa: E402

ROW_KEYS = {"method", "rot_mean_deg", "rot_median_deg", "trans_mean", "trans_median", "acc_5deg", "acc_5deg_005",
            "flip_rate"}


@pytest.mark.parametrize("mode", ["complete", "partial"])
def test_train_resume_calibrate_eval(tmp_path, data_root, mode):
    out, cache = tmp_path / "run", tmp_path / "cache"
    common = ["--category", "airplane", "--data-root", str(data_root)]
    train = ["train", *common, "--mode", mode, "--preset", "tiny", "--batch-size", "2", "--train-limit", "4",
             "--val-size", "10", "--val-every", "2", "--out", str(out), "--cache-dir", str(cache), "--views", "2"]
    assert main(train + ["--steps", "2"]) == 0
    ck = load_checkpoint(out / "latest.pt")
    assert ck["step"] == 2 and ck["partial"] == (mode == "partial") and ck["scale"] == 2.0
    assert ck["training"]["history"][-1]["step"] == 2                # validation ran and was logged
    assert main(train + ["--steps", "3", "--resume"]) == 0
    ck = load_checkpoint(out / "latest.pt")
    assert ck["step"] == 3 and ck["optimizer"] is not None

    assert main(["calibrate", "--checkpoint", str(out / "latest.pt"), "--num", "8", "--cache-dir", str(cache)]) == 0
    cal = load_checkpoint(out / "latest.pt")["calibration"]
    assert len(cal["rotation"]) == 3 and len(cal["translation"]) == 3 and 4 <= cal["n"] <= 8
    if mode == "complete":                   # trained on another machine: its folders are not here → the defaults
        moved = load_checkpoint(out / "latest.pt")
        moved["training"]["config"].update(data_root=str(tmp_path / "gone" / "data"), cache_dir=str(tmp_path / "gone"))
        torch.save(moved, tmp_path / "moved.pt")
        assert main(["calibrate", "--checkpoint", str(tmp_path / "moved.pt"), "--num", "4"]) == 0
        assert not (tmp_path / "gone").exists()

    js, png = tmp_path / "r.json", tmp_path / "r.png"
    assert main(["eval", "--checkpoint", str(out / "latest.pt"), *common, "--mode", mode, "--limit", "2",
                 "--icp-templates", "1", "--icp-iters", "3", "--cache-dir", str(cache), "--json", str(js),
                 "--plot", str(png)]) == 0
    res = json.loads(js.read_text())
    assert set(res) == {"category", "mode", "n", "rows"} and res["mode"] == mode and res["n"] == 10
    assert [r["method"] for r in res["rows"]] == ["equipose", "icp60"]
    for r in res["rows"]:
        assert set(r) == ROW_KEYS
        assert 0 <= r["rot_median_deg"] <= 180 and 0 <= r["acc_5deg"] <= 1
    assert png.read_bytes()[:4] == b"\x89PNG"

    warm = tmp_path / "warm"                                         # --init: weights only, fresh step counter
    assert main(train[:-10] + ["--val-every", "100", "--out", str(warm), "--cache-dir", str(cache), "--views", "2",
                               "--steps", "1", "--init", str(out / "latest.pt"), "--freeze", "inv_head,decoder"]) == 0
    w = load_checkpoint(warm / "latest.pt")
    assert w["step"] == 1 and w["training"]["config"]["init"] == str(out / "latest.pt")
    src = load_checkpoint(out / "latest.pt")["state_dict"]
    dec = [k for k in src if k.startswith(("decoder.", "inv_head."))]
    assert dec and all(torch.equal(w["state_dict"][k], src[k]) for k in dec)          # frozen (incl. BN stats)
    assert any(not torch.equal(w["state_dict"][k], src[k]) for k in src if k.startswith("pose_head.") and
               src[k].is_floating_point())                                             # trained

    budget = tmp_path / "budget"                                     # --minutes: stops at the budget, validated
    assert main(train[:-10] + ["--val-every", "100", "--out", str(budget), "--cache-dir", str(cache), "--views", "2",
                               "--steps", "50", "--minutes", "1e-6"]) == 0
    b = load_checkpoint(budget / "latest.pt")
    assert b["step"] == 1 and b["training"]["history"][-1]["step"] == 1
    assert b["training"]["history"][-1]["train_minutes"] > 0


def test_symmetric_category_trains_with_the_axial_symmetry_prior(tmp_path, data_root):
    """can = ModelNet bottles + procedural cylinders; --symmetry-weight adds the canonical-shape symmetry loss."""
    out = tmp_path / "can"
    assert main(["train", "--category", "can", "--mode", "complete", "--data-root", str(data_root), "--preset", "tiny",
                 "--batch-size", "2", "--train-limit", "3", "--val-size", "10", "--val-every", "2", "--steps", "2",
                 "--symmetry-weight", "1.0", "--out", str(out)]) == 0
    ck = load_checkpoint(out / "latest.pt")
    assert ck["step"] == 2 and ck["symmetry"] == "continuous:z"
    assert ck["training"]["config"]["symmetry_weight"] == 1.0


def test_ddp_two_processes_gloo(tmp_path, data_root):
    out = tmp_path / "ddp"
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
           "-m", "equipose.cli", "train", "--category", "airplane", "--mode", "complete", "--preset", "tiny",
           "--steps", "2", "--batch-size", "2", "--train-limit", "8", "--val-size", "5", "--val-every", "2",
           "--device", "cpu", "--out", str(out), "--data-root", str(data_root)]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
    ck = load_checkpoint(out / "latest.pt")
    assert ck["step"] == 2 and ck["training"]["world_size"] == 2


def test_eval_exported_model_matches_checkpoint(tmp_path, data_root):
    """--model evaluates the shipped ONNX through equipose.PoseEstimator; it agrees with the checkpoint path."""
    pytest.importorskip("onnx")
    out = tmp_path / "run"
    common = ["--category", "airplane", "--data-root", str(data_root)]
    assert main(["train", *common, "--mode", "complete", "--preset", "tiny", "--batch-size", "2", "--train-limit", "4",
                 "--val-size", "5", "--steps", "1", "--out", str(out)]) == 0
    assert main(["calibrate", "--checkpoint", str(out / "latest.pt"), "--num", "4"]) == 0
    onnx_path = tmp_path / "m.onnx"
    assert main(["export", "--checkpoint", str(out / "latest.pt"), "-o", str(onnx_path)]) == 0
    rows = {}
    for src in (["--checkpoint", str(out / "latest.pt")], ["--model", str(onnx_path)]):
        js = tmp_path / f"{src[0][2:]}.json"
        assert main(["eval", *src, *common, "--mode", "complete", "--limit", "2", "--icp-templates", "1",
                     "--icp-iters", "2", "--json", str(js)]) == 0
        rows[src[0]] = json.loads(js.read_text())["rows"]
    a, b = rows["--checkpoint"][0], rows["--model"][0]
    assert a["method"] == b["method"] == "equipose"
    assert abs(a["trans_mean"] - b["trans_mean"]) < 1e-3
    assert abs(a["rot_median_deg"] - b["rot_median_deg"]) < 0.1 and abs(a["rot_mean_deg"] - b["rot_mean_deg"]) < 0.5
