"""``load_kernels`` (called when a ``PoseEstimator`` is built) runs every compiled kernel a frame reaches, so the first
frame after an install does not compile any (1.7 s for the axis line of the demo's cup in v0.55). Checked in a fresh
interpreter: in this one, earlier tests have already run most kernels."""
import json
import subprocess
import sys

PROBE = r'''
import importlib, json, pkgutil
import numpy as np
from numba.core.registry import CPUDispatcher
import equipose
from equipose import PoseEstimator
from equipose.samples import sample_frame, sample_objects

def signatures():
    out = {}
    for info in pkgutil.walk_packages(equipose.__path__, "equipose."):
        if info.name.startswith(("equipose.train", "equipose.export")):
            continue
        for name, value in vars(importlib.import_module(info.name)).items():
            if isinstance(value, CPUDispatcher):
                out[f"{value.py_func.__module__}.{name}"] = len(value.signatures)
    return out

rng = np.random.default_rng(0)
cube = rng.uniform(-0.04, 0.04, (2000, 3))
cube[np.arange(2000), rng.integers(0, 3, 2000)] = np.where(rng.random(2000) < 0.5, -0.04, 0.04)
models = ["cup-tabletop", "bowl-tabletop", "mug-tabletop", "can-tabletop", "sofa-partial", "chair-complete"]
ests = [PoseEstimator(m, threads=1) for m in models] + [PoseEstimator("can-tabletop", threads=1, model_points=cube)]
before = signatures()
frame = sample_frame("table_mug")
boxes = [o["box"] for o in sample_objects("table_mug")]
for est in ests:
    for up in ((None, "plane") if est.instance is None else (None,)):
        est.predict_batch(frame.depth, frame.K, boxes=boxes, image_size=frame.image_size, up=up)
    est.predict_auto(frame.depth, frame.K, image_size=frame.image_size)
after = signatures()
print(json.dumps(sorted(k for k, n in after.items() if n > before.get(k, 0))))
'''


def test_the_first_frames_meet_no_kernel_that_was_not_loaded():
    run = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    assert json.loads(run.stdout.strip().splitlines()[-1]) == []
