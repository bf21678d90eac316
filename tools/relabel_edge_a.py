"""Rename the preset of shipped models trained with the session-1 `edge` configuration to `edge-a`.

Session 4 made `edge` the quotient configuration (edge-q). Files exported earlier say preset "edge" in their metadata
but carry edge-a's configuration (``model_config``, ``quotient`` absent). This rewrites ``preset`` and
``model_config.name`` (and the training record's preset) of exactly those files; weights, calibration and stored
metrics are untouched. Usage: ``python tools/relabel_edge_a.py [sdk/models]`` (prints what it changed).
"""
from __future__ import annotations

import json
import pathlib
import sys

import onnx


def relabel(path: pathlib.Path) -> bool:
    model = onnx.load(str(path))
    props = {p.key: p for p in model.metadata_props}
    cfg = json.loads(props["model_config"].value)
    if props["preset"].value != "edge" or cfg.get("quotient", False):
        return False
    props["preset"].value = "edge-a"
    cfg["name"] = "edge-a"
    props["model_config"].value = json.dumps(cfg)
    if "training" in props:
        training = json.loads(props["training"].value)
        if training.get("preset") == "edge":
            training["preset"] = "edge-a"
            props["training"].value = json.dumps(training)
    onnx.save(model, str(path))
    return True


def main(folder: str = "sdk/models") -> int:
    for path in sorted(pathlib.Path(folder).glob("*.onnx")):
        if relabel(path):
            print(f"{path}: preset edge → edge-a")
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
