"""Models shipped with the package (ONNX files with equipose metadata; ``equipose models`` lists them).

Each file's metadata carries its category, preset, scale, calibration and its own test metrics (``metrics``, written
by ``equipose eval --model M --store-metrics``); ``X.int8.onnx`` is the dynamic-int8 copy of ``X.onnx``.
``cup-tabletop.onnx`` is the demo model. Trained on ModelNet40 (academic use only) and OCRTOC/YCB data: research use.
"""
from __future__ import annotations

import pathlib

__all__ = ["MODELS_DIR", "DEMO_MODEL", "demo_model_path", "list_models", "model_names", "resolve_model", "model_card",
           "model_cards"]

MODELS_DIR = pathlib.Path(__file__).resolve().parent
DEMO_MODEL = "cup-tabletop.onnx"


def demo_model_path() -> pathlib.Path:
    """Path of the bundled demo model (the trained tabletop cup / mug model)."""
    return MODELS_DIR / DEMO_MODEL


def list_models() -> list:
    """Paths of all ``.onnx`` files shipped in this package, sorted."""
    return sorted(MODELS_DIR.glob("*.onnx"))


def _key(name: str) -> str:
    return name.lower().replace("-", "_").removesuffix(".onnx")


def model_names() -> list:
    """Names of the shipped models (file stems with '-' for '_'), e.g. ``cup-tabletop``, ``cup-tabletop.int8``."""
    return [p.stem.replace("_", "-") for p in list_models()]


def resolve_model(name_or_path) -> pathlib.Path:
    """A model file path from a path or a shipped model's name (case-, '-'/'_'- and '.onnx'-insensitive).

    Raises ``ModelFormatError`` naming the shipped models when neither a file nor a known name matches.
    """
    from equipose.errors import ModelFormatError
    path = pathlib.Path(name_or_path)
    if path.is_file():
        return path
    key = _key(str(name_or_path))
    for p in list_models():
        if _key(p.name) == key:
            return p
    raise ModelFormatError(f"model {str(name_or_path)!r} is neither a file nor a shipped model; shipped: "
                           f"{', '.join(model_names()) or 'none'} (see 'equipose models')")


def model_card(path) -> dict:
    """One model's listing (JSON-ready): name, path, category, mode, preset, precision, size, test metrics, training.

    Reads the metadata only (onnx protobuf via onnxruntime's model metadata; no inference). ``precision`` comes from
    the metadata key (older files: from the ``.int8`` name suffix).
    """
    from equipose.estimator import PoseEstimator
    path = pathlib.Path(path)
    est = PoseEstimator(path, threads=1)
    meta = est.metadata
    precision = meta.get("precision") or ("int8" if path.name.endswith(".int8.onnx") else "fp32")
    training = meta.get("training") or {}
    return {"name": path.name.removesuffix(".onnx").replace("_", "-"), "path": str(path),
            "category": est.category, "mode": "partial" if meta["partial"] else "complete", "preset": meta["preset"],
            "precision": precision, "size_mb": round(path.stat().st_size / 1e6, 3), "num_points": est.num_points,
            "scale_m_per_unit": est.scale, "symmetry": est.symmetry, "random_init": bool(meta["random_init"]),
            "metrics": meta.get("metrics") or {}, "training": training}


def model_cards(paths=None) -> list:
    """``model_card`` of each path (default: every shipped model)."""
    return [model_card(p) for p in (paths or list_models())]
