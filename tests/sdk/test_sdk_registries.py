"""Extension points: a new depth source and a new metric are each one registration; shipped weights bind to presets
by ``arch.tag``."""
import json

import numpy as np
import pytest

from equipose import sources
from equipose.eval import metrics
from equipose.sources.base import _REGISTRY


def test_bundled_sources_go_through_the_registry():
    names = {e.name for e in sources.registered_sources()}
    assert {"folder", "mcap", "pcd", "oak"} <= names


def test_a_toy_depth_source_is_one_registration(tmp_path):
    @sources.register_source("toy", suffixes=(".toy",))
    class ToySource(sources.FrameSource):
        def __init__(self, path):
            self.path = path

        def __iter__(self):
            K = np.array([[100.0, 0, 3.5], [0, 100.0, 2.5], [0, 0, 1]])
            yield sources.Frame(depth=np.full((6, 8), 500, np.uint16), K=K)

    try:
        (tmp_path / "x.toy").write_text("toy")
        src = sources.open_source(tmp_path / "x.toy")
        assert isinstance(src, ToySource) and src.path == tmp_path / "x.toy"
        (frame,) = list(src)
        assert frame.shape == (6, 8)
    finally:
        _REGISTRY.pop("toy", None)
    with pytest.raises(sources.base.SourceError):
        sources.open_source(tmp_path / "x.toy")


def test_a_toy_metric_is_one_registration():
    r, t = np.array([1.0, 3.0, 12.0, 170.0]), np.array([0.01, 0.2, 0.01, 0.03])
    before = metrics.summarize("ours", r, t)
    assert "acc_10deg" not in before and "acc_10deg" not in metrics.ROW_KEYS
    metrics.register_metric("acc_10deg")(lambda rot, trans: float(np.mean(rot <= 10.0)))
    try:
        row = metrics.summarize("ours", r, t)
        assert row["acc_10deg"] == pytest.approx(0.5)
        assert {k: row[k] for k in before} == before                           # the bundled columns unchanged
        assert metrics.ROW_KEYS[-1] == "acc_10deg" and set(row) == set(metrics.row_keys())
    finally:
        metrics.unregister_metric("acc_10deg")
    assert "acc_10deg" not in metrics.summarize("ours", r, t)


def test_shipped_weights_are_named_arch_dot_tag():
    from equipose.core.presets import get_preset
    from equipose.models import WEIGHTS, demo_model_path, full_name, list_models, resolve_model
    from equipose.runtime.session import read_metadata
    tags = {p.name.removesuffix(".onnx").removesuffix(".int8") for p in list_models()}
    assert tags == set(WEIGHTS)                                                 # every file bound, no stale entry
    for p in list_models():
        tag = p.name.removesuffix(".onnx")
        name = full_name(tag)
        assert resolve_model(name) == p == resolve_model(tag)                   # arch.tag and the short alias
        cfg = json.loads(json.dumps(get_preset(name).to_dict()))                # tuples → lists, as stored
        meta = read_metadata(p)["model_config"]
        skip = {"name", "description"}
        assert {k: v for k, v in cfg.items() if k not in skip} == {k: v for k, v in meta.items() if k not in skip}
    assert resolve_model("edge.cup-tabletop") == demo_model_path()
    with pytest.raises(ValueError, match="ships with preset"):
        resolve_model("paper.cup-tabletop")


def test_shipped_weights_hold_no_decayed_values():
    """No shipped graph initializer or decoded turn-classifier weight is a nonzero below 1e-20: such weights (trained
    ones decay to 1e-38) give subnormal products, ~100× slower on x86 CPUs (docs/benchmarks.md, v0.50)."""
    import onnx
    from onnx import numpy_helper

    from equipose.core.model_file import read_metadata
    from equipose.models import list_models
    for p in list_models():
        if p.name.endswith(".int8.onnx"):
            continue
        tensors = [(i.name, numpy_helper.to_array(i)) for i in onnx.load(str(p), load_external_data=False).graph.initializer]
        turn = read_metadata(p).get("turn_classifier")
        if turn is not None:
            tensors += [(f"turn {part} {k}", W) for part in ("point", "head") for k, (W, _) in enumerate(turn["weights"][part])]
        for name, a in tensors:
            if a.dtype == np.float32:
                tiny = (a != 0) & (np.abs(a) < 1e-20)
                assert not tiny.any(), (p.name, name, int(tiny.sum()))
