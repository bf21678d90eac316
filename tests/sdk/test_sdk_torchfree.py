"""The runtime works with torch unavailable: import, estimator, demo CLI (subprocess with a meta-path blocker)."""
import subprocess
import sys
import textwrap

BLOCKER = textwrap.dedent("""
    import sys, importlib.abc
    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name == "torch" or name.startswith("torch."):
                raise ImportError("torch is blocked in this test")
    sys.meta_path.insert(0, Block())
""")


def test_runtime_without_torch(tmp_path):
    code = BLOCKER + textwrap.dedent(f"""
        import numpy as np
        import equipose
        from equipose import PoseEstimator, PoseResult
        from equipose.models import demo_model_path
        from equipose.samples import sample_path
        from equipose.sources import open_source
        est = PoseEstimator(demo_model_path(), threads=1)
        frame = next(iter(open_source(sample_path())))
        r = est.predict(frame.depth, frame.K, box=(328, 233, 169, 146), image_size=frame.image_size)
        assert isinstance(r, PoseResult) and np.isfinite(r.translation).all()
        from equipose.cli import main
        assert main(["demo", "--out", r"{tmp_path / 'demo'}", "--threads", "1"]) == 0
        assert "torch" not in sys.modules, "torch was imported"
        print("OK torch-free")
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-3000:]
    assert "OK torch-free" in p.stdout and "RANDOM WEIGHTS" not in p.stdout          # the trained demo model
    assert "symmetry axis vs table normal" in p.stdout
    assert (tmp_path / "demo" / "overlay.png").is_file() and (tmp_path / "demo" / "results.json").is_file()


def test_blocker_really_blocks_torch():
    p = subprocess.run([sys.executable, "-c", BLOCKER + "import torch"], capture_output=True, text=True, timeout=60)
    assert p.returncode != 0 and "blocked" in p.stderr
