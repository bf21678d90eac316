"""Recovering a trainable checkpoint from an exported ONNX file, and the tracked long-run state built on it."""
import json
import pathlib

import numpy as np
import pytest
import torch

from equipose.errors import ConfigError
from equipose.core.geometry import farthest_point_order
from equipose.models import resolve_model
from equipose.train.fitting.checkpoint import model_from_checkpoint
from equipose.train.network.onnx_weights import checkpoint_from_onnx

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUTPUTS = ("canonical_shape", "hypothesis_rotations", "hypothesis_translations", "hypothesis_scores")


def _inputs(n, batch=3, seed=0):
    rng = np.random.default_rng(seed)
    xs = []
    for _ in range(batch):
        p = rng.standard_normal((4 * n, 3)) * np.array([0.3, 0.2, 0.1])
        xs.append(p[farthest_point_order(p, n)])
    return np.stack(xs).astype(np.float32)


def _max_diff(model, onnx_path, x):
    import onnxruntime as ort
    from equipose.testing import onnx_model_fn
    out = onnx_model_fn(ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"]))(x)
    got = [out[k] for k in OUTPUTS]
    with torch.no_grad():
        ref = model(torch.from_numpy(x))
    return max(float(np.abs(ref[k].numpy() - g).max()) for k, g in zip(OUTPUTS, got)), ref, got


@pytest.mark.parametrize("partial", [False, True])
def test_recovered_random_model_matches_its_export(tmp_path, partial):
    from equipose.export.onnx_export import export_model
    from equipose.train.network.model import EquiPoseNet
    torch.manual_seed(3)
    net = EquiPoseNet("edge", partial=partial)
    with torch.no_grad():                        # trained-like weights: no zero biases, non-trivial BatchNorm statistics
        for name, t in net.state_dict().items():
            if t.is_floating_point():
                t.add_(0.05 * torch.randn_like(t)).abs_() if "running_var" in name else t.add_(0.05 * torch.randn_like(t))
    path = export_model(net.eval(), tmp_path / "m.onnx", category="x", scale=1.0)
    ck = checkpoint_from_onnx(path)
    model, _ = model_from_checkpoint(ck)
    assert isinstance(model, EquiPoseNet) and model.partial == partial
    err, _, _ = _max_diff(model, path, _inputs(model.num_points))
    assert err < 1e-4
    # BatchNorm layers fused by the exporter were re-created with measured statistics: not the identity defaults
    bns = [m for m in model.modules() if isinstance(m, torch.nn.BatchNorm1d)]
    assert bns and any(not torch.allclose(m.running_var, torch.ones_like(m.running_var)) for m in bns)


def test_recovered_shipped_model_keeps_best_hypotheses():
    path = ROOT / "sdk" / "models" / "car-complete.onnx"
    ck = checkpoint_from_onnx(path)
    model, _ = model_from_checkpoint(ck)
    err, ref, got = _max_diff(model, path, _inputs(model.num_points))
    assert err < 1e-4
    assert np.array_equal(ref["hypothesis_scores"].argmin(1).numpy(), got[3].argmin(1))
    assert ck["step"] > 0 and ck["category"] == "car" and np.allclose(np.asarray(ck["calibration"]["rotation"]) @
                                                                       np.asarray(ck["calibration"]["rotation"]).T,
                                                                       np.eye(3), atol=1e-5)


def test_recovery_refuses_int8_and_foreign_files(tmp_path):
    with pytest.raises(ConfigError, match="fp32"):
        checkpoint_from_onnx(resolve_model("car-complete.int8"))          # the int8 copy, built if need be
    with pytest.raises(ConfigError, match="does not exist"):
        checkpoint_from_onnx(tmp_path / "none.onnx")


def test_tracked_state_folders_are_complete():
    state = ROOT / "train" / "state"
    folders = sorted(p.parent for p in state.glob("*/manifest.json"))
    assert folders, "no tracked training state"
    for f in folders:
        man = json.loads((f / "manifest.json").read_text())
        cfg = json.loads((f / "config.json").read_text())
        assert (f / "latest.pt").is_file()
        assert man["name"] == f.name and man["steps"] >= man["history"][0].get("steps_after", 0) > 0
        assert cfg["out"] == f"train/state/{f.name}"
        if "candidate_for" in man:                                       # a wider student that may replace a model
            assert (ROOT / "sdk" / "models" / f"{man['candidate_for']}.onnx").is_file()
            assert cfg["category"] == man["category"] and cfg["preset"] == man["preset"]
        if man["role"] == "student":
            assert (ROOT / cfg["teacher"]).is_file(), f"{f.name}: teacher {cfg['teacher']} missing"


def test_seed_and_one_slice_accumulate_steps(tmp_path, data_root):
    from equipose.train.lanes import long_runs
    state = tmp_path / "repo" / "train" / "state"
    long_runs.seed_model("bottle-complete", state_dir=state, data_root=data_root)
    before = json.loads((state / "bottle-complete" / "manifest.json").read_text())
    cfg = json.loads((state / "bottle-complete" / "config.json").read_text())
    cfg.update(val_size=4, calib_size=8, train_limit=12)
    (state / "bottle-complete" / "config.json").write_text(json.dumps(cfg))
    durable = (state / "bottle-complete" / "config.json").read_text()
    long_runs.run_slice("bottle-complete", 0.001, state_dir=state, data_root=data_root, log=lambda *a: None)
    assert (state / "bottle-complete" / "config.json").read_text() == durable   # slice overrides stay transient
    after = json.loads((state / "bottle-complete" / "manifest.json").read_text())
    assert after["step_counter"] > before["step_counter"]
    assert after["steps"] - before["steps"] == after["step_counter"] - before["step_counter"]
    assert after["history"][-1]["val_rot_median_deg"] is not None
    ck = torch.load(state / "bottle-complete" / "latest.pt", map_location="cpu", weights_only=True)
    assert ck["optimizer"] is not None and ck["step"] == after["step_counter"]
    assert after["history"][-1]["batch_size"] == cfg["batch_size"] and after["history"][-1]["device"] == "cpu"
    long_runs.run_slice("bottle-complete", 0.001, state_dir=state, data_root=data_root, batch_size=3,
                        log=lambda *a: None)                                   # e.g. a larger batch on a lent GPU
    again = json.loads((state / "bottle-complete" / "manifest.json").read_text())
    assert again["history"][-1]["batch_size"] == 3 and again["step_counter"] > after["step_counter"]
    assert (state / "bottle-complete" / "config.json").read_text() == durable   # for that slice only
    ck = torch.load(state / "bottle-complete" / "latest.pt", map_location="cpu", weights_only=True)
    b = cfg["batch_size"]                      # the lr schedule counts samples, so a batch override keeps its epoch
    seen = after["step_counter"] * b + (again["step_counter"] - after["step_counter"]) * 3
    assert ck["training"]["samples_seen"] == seen
