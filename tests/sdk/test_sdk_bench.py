"""``equipose bench``: every backend runs on the bundled frame and the JSON has the documented fields (no timing
thresholds: speed goals are met in benchmarks, not in tests)."""
import json
import subprocess
import sys

import pytest

from equipose.bench.harness import format_table, percentiles, run_benchmark


def test_percentiles():
    p = percentiles([1.0, 2.0, 3.0, 4.0, 100.0])
    assert p["p50_ms"] == 3.0 and p["max_ms"] == 100.0 and 4.0 < p["p95_ms"] < 100.0


def test_bench_all_backends(tiny_model, tmp_path):
    pytest.importorskip("torch")
    res = run_benchmark(str(tiny_model), ("onnxruntime-fp32", "onnxruntime-int8", "torch", "icp60"), threads=1,
                        objects=2, runs=3, warmup=1)
    rows = {r["backend"]: r for r in res["rows"]}
    assert set(rows) == {"onnxruntime-fp32", "onnxruntime-int8", "torch", "icp60"}
    for r in rows.values():
        assert "error" not in r, r
        assert 0 < r["p50_ms"] <= r["p95_ms"] <= r["max_ms"]
        assert r["peak_rss_mb"] > 0 and r["fps"] > 0 and r["objects"] == 2
        assert set(r["stages"]) == {"crop", "fps", "inference", "selection"}
    # the torch backend rebuilt the export's weights from its seed: same outputs as the ONNX file
    assert rows["torch"]["note"].startswith("same weights") and rows["torch"]["parity_max_abs"] < 1e-3
    assert res["bound_ms"] > 0 and res["macs"] > 0
    assert all(r["threads_used"] == 1 for r in rows.values())
    fp32, torch_row = rows["onnxruntime-fp32"], rows["torch"]
    assert res["ratios"]["torch"]["end_to_end"] == pytest.approx(torch_row["p50_ms"] / fp32["p50_ms"])
    assert res["ratios"]["torch"]["inference"] == pytest.approx(
        torch_row["stages"]["inference"]["p50_ms"] / fp32["stages"]["inference"]["p50_ms"])
    table = format_table(res)
    assert "onnxruntime-int8" in table and "× fp32" in table
    host = res["host"]
    assert host["cores"] >= 1 and host["cpu"] and (host["busy"] is None or 0.0 <= host["busy"] <= 1.0)
    assert f"{host['cores']} logical CPUs" in table
    res["host"] = {**host, "busy": 0.9}                                         # a busy host is reported as such
    assert "not idle figures" in format_table(res)
    res["host"] = {**host, "busy": 0.0}
    assert "not idle figures" not in format_table(res)


def test_bench_cli_json(tiny_model, tmp_path):
    out = tmp_path / "b.json"
    p = subprocess.run([sys.executable, "-m", "equipose.cli", "bench", "--model", str(tiny_model), "--threads", "1",
                        "--runs", "2", "--warmup", "1", "--compare", "icp", "--json", str(out)],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stderr
    data = json.loads(out.read_text())
    assert data["threads"] == 1 and data["points"] == 256
    assert [r["backend"] for r in data["rows"]] == ["onnxruntime-fp32", "icp60"]
    for r in data["rows"]:
        assert {"backend", "p50_ms", "p95_ms", "max_ms", "fps", "peak_rss_mb"} <= set(r)


def test_bench_threads_used_follows_the_adaptive_policy(tiny_model, tmp_path):
    """A light model's single object runs on one onnxruntime thread unless --fixed-threads; torch keeps the budget."""
    for flag, expect in (([], 1), (["--fixed-threads"], 2)):
        out = tmp_path / f"t{expect}.json"
        p = subprocess.run([sys.executable, "-m", "equipose.cli", "bench", "--model", str(tiny_model), "--threads", "2",
                            "--runs", "2", "--warmup", "1", "--compare", "", "--json", str(out), *flag],
                           capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        data = json.loads(out.read_text())
        assert data["adaptive_threads"] is (not flag) and data["rows"][0]["threads_used"] == expect


def test_bench_cli_rejects_bad_compare(tiny_model):
    p = subprocess.run([sys.executable, "-m", "equipose.cli", "bench", "--model", str(tiny_model), "--compare", "gpu"],
                       capture_output=True, text=True)
    assert p.returncode == 2 and "--compare" in p.stderr


def test_bench_cli_stage_options_reach_every_run(tiny_model, tmp_path):
    """--stages mirrors PoseEstimator(stages=...): a stage switched off leaves the measured pipeline."""
    pipelines = {}
    for stages in (None, '{"confidence": false}'):
        out = tmp_path / f"s{stages is None}.json"
        p = subprocess.run([sys.executable, "-m", "equipose.cli", "bench", "--model", str(tiny_model), "--threads", "1",
                            "--runs", "2", "--warmup", "1", "--compare", "", "--json", str(out),
                            *(["--stages", stages] if stages else [])], capture_output=True, text=True)
        assert p.returncode == 0, p.stderr
        data = json.loads(out.read_text())
        assert data["stages_options"] == (json.loads(stages) if stages else None)
        pipelines[stages] = set(data["rows"][0]["pipeline"])
    assert "confidence" in pipelines[None] and "confidence" not in pipelines['{"confidence": false}']
    p = subprocess.run([sys.executable, "-m", "equipose.cli", "bench", "--model", str(tiny_model), "--stages", "[1]"],
                       capture_output=True, text=True)
    assert p.returncode != 0 and "--stages" in p.stderr
