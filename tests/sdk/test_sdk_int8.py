"""int8 copies built from their fp32 files on first use (``equipose.models.int8``): where, when rebuilt, which
metadata they carry, and that the shipped ones are current."""
import hashlib
import json
import shutil

import numpy as np
import pytest

from equipose.core.model_file import read_metadata_props
from equipose.models import WEIGHTS, MODELS_DIR, resolve_model, resolve_model_file
from equipose.models import int8 as int8_mod
from equipose.models.int8 import OVERRIDES_KEY, SOURCE_KEY, ensure_int8, int8_path_for, is_derived_int8


def _sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def fp32(tmp_path, tiny_model):
    path = tmp_path / "m.onnx"
    shutil.copyfile(tiny_model, path)
    return path


def _outputs(path, seed=0):
    import onnxruntime as ort

    from equipose.core.model_file import read_metadata
    from equipose.runtime.session import GraphIO
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    meta = read_metadata(path)
    x = (np.random.default_rng(seed).standard_normal((2, int(meta["num_points"]), 3)) * 0.3).astype(np.float32)
    return sess.run(None, GraphIO(sess, meta).feeds(x))


def test_built_beside_on_first_use_and_deterministic(fp32):
    q = int8_path_for(fp32)
    assert not q.exists()
    assert resolve_model_file(str(q)) == q and q.is_file()                    # the path of a copy not yet built
    meta = read_metadata_props(q)
    assert meta["precision"] == "int8" and meta[SOURCE_KEY] == _sha(fp32) and OVERRIDES_KEY not in meta
    first = q.read_bytes()
    q.unlink()
    assert ensure_int8(fp32) == q and q.read_bytes() == first                  # the same bytes when rebuilt
    mtime = q.stat().st_mtime_ns
    assert ensure_int8(fp32) == q and q.stat().st_mtime_ns == mtime            # current: not rebuilt
    assert is_derived_int8(q) and not is_derived_int8(fp32)


def test_rebuilt_when_fp32_changes_and_overrides_kept(fp32):
    from equipose.export.onnx_export import update_metadata
    q = ensure_int8(fp32)
    update_metadata(q, metrics={"rot_median_deg": 9.0})                       # int8's own entry → fp32's overrides
    assert json.loads(read_metadata_props(fp32)[OVERRIDES_KEY]) == {"metrics": '{"rot_median_deg": 9.0}'}
    assert json.loads(read_metadata_props(q)["metrics"]) == {"rot_median_deg": 9.0}
    assert read_metadata_props(q)[SOURCE_KEY] == _sha(fp32)                   # rebuilt from the updated fp32 file
    update_metadata(fp32, metrics={"rot_median_deg": 1.0}, shape_prior="cylinder")
    assert read_metadata_props(q)[SOURCE_KEY] != _sha(fp32)                   # stale until resolved
    q2 = resolve_model_file(q)
    meta = read_metadata_props(q2)
    assert q2 == q and meta[SOURCE_KEY] == _sha(fp32)
    assert meta["shape_prior"] == "cylinder"                                  # shared entries follow the fp32 file
    assert json.loads(meta["metrics"]) == {"rot_median_deg": 9.0}             # the int8 one stays its own
    assert json.loads(read_metadata_props(fp32)["metrics"]) == {"rot_median_deg": 1.0}
    update_metadata(q, shape_prior="cylinder", metrics={"rot_median_deg": 1.0})   # equal to the fp32 entries
    assert json.loads(read_metadata_props(fp32)[OVERRIDES_KEY]) == {}         # the copy follows the fp32 file


def test_read_only_folder_builds_in_cache(fp32, tmp_path, monkeypatch):
    monkeypatch.setenv("EQUIPOSE_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(int8_mod.os, "access", lambda path, mode: False)
    q = ensure_int8(fp32)
    assert q == tmp_path / "cache" / "models" / _sha(fp32)[:16] / "m.int8.onnx"
    assert not int8_path_for(fp32).exists() and read_metadata_props(q)[SOURCE_KEY] == _sha(fp32)


def test_stand_alone_int8_file_left_alone(fp32):
    q = ensure_int8(fp32)
    from equipose.models.model_io import read_model_file, write_model_file
    proto = read_model_file(q)
    kept = [(p.key, p.value) for p in proto.metadata_props if p.key != SOURCE_KEY]
    del proto.metadata_props[:]
    for k, v in kept:
        proto.metadata_props.add(key=k, value=v)
    write_model_file(proto, q)                                                # no int8_source: not a built copy
    before = q.read_bytes()
    assert ensure_int8(fp32) == q and resolve_model_file(q) == q and q.read_bytes() == before


def test_shipped_int8_copies_current_and_close_to_fp32():
    for tag in WEIGHTS:
        q = resolve_model(f"{tag}.int8")
        fp32 = MODELS_DIR / f"{tag}.onnx"
        meta = read_metadata_props(q)
        assert meta[SOURCE_KEY] == _sha(fp32) and meta["precision"] == "int8", tag
        assert set(json.loads(read_metadata_props(fp32)[OVERRIDES_KEY])) == {"metrics", "refine_calibration"}, tag
    a, b = _outputs(MODELS_DIR / "car-partial.onnx"), _outputs(resolve_model("car-partial.int8"))
    assert 0 < np.abs(a[0] - b[0]).max() < 0.08                               # the contract's int8 tolerance
