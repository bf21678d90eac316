"""Models shipped with the package (ONNX files with equipose metadata; ``equipose models`` lists them).

Each file's metadata carries its category, preset, scale, calibration and its own test metrics (``metrics``, written
by ``equipose eval --model M --store-metrics``); ``X.int8.onnx`` is the dynamic-int8 copy of ``X.onnx``, built from
it on first use (``equipose.models.int8``: the same outputs, bit for bit, as the file measured at release).
``cup-tabletop.onnx`` is the demo model. Trained on ModelNet40 (academic use only) and OCRTOC/YCB data: research use.

Names follow ``arch.tag`` (as timm does): ``arch`` is the architecture preset (``equipose.core.presets``), ``tag``
the weights (``category-mode``, plus ``.int8`` for the quantised copy), e.g. ``edge.cup-tabletop``. The short tag
alone (``cup-tabletop``) stays a valid alias. ``WEIGHTS`` binds every shipped tag to its preset.
"""
from __future__ import annotations

import os
import pathlib

from equipose.models.int8 import INT8_SUFFIX, ensure_int8, fp32_path_for, int8_path_for

__all__ = ["MODELS_DIR", "DEMO_MODEL", "WEIGHTS", "demo_model_path", "list_models", "resolve_model_file", "model_names",
           "full_name", "result_symmetry", "split_name", "resolve_model", "model_card", "model_cards"]

MODELS_DIR = pathlib.Path(__file__).resolve().parent
DEMO_MODEL = "cup-tabletop.onnx"

# tag (file stem without precision) → architecture preset; the preset's configuration equals the file's model_config
WEIGHTS = {tag: "edge" for tag in (
    "airplane-complete", "airplane-partial", "bottle-complete", "bottle-partial", "bowl-tabletop", "can-tabletop",
    "car-complete", "car-partial", "chair-complete", "chair-partial", "cup-tabletop", "laptop-partial", "mug-tabletop",
    "sofa-complete", "sofa-partial")}


def demo_model_path() -> pathlib.Path:
    """Path of the bundled demo model (the trained tabletop cup / mug model)."""
    return MODELS_DIR / DEMO_MODEL


def _fp32_files() -> list:
    return sorted(p for p in MODELS_DIR.glob("*.onnx") if not p.name.endswith(INT8_SUFFIX))


def list_models() -> list:
    """Paths of the shipped models, sorted by name: each fp32 file and its int8 copy (built on first use)."""
    return sorted([p for f in _fp32_files() for p in (f, ensure_int8(f))], key=lambda p: _key(p.name))


def _key(name: str) -> str:
    return name.lower().replace("-", "_").removesuffix(".onnx")


def model_names() -> list:
    """Names of the shipped models (file stems with '-' for '_'), e.g. ``cup-tabletop``, ``cup-tabletop.int8``."""
    return sorted(n for f in _fp32_files() for n in (f.stem.replace("_", "-"), int8_path_for(f).stem.replace("_", "-")))


def split_name(name: str) -> tuple:
    """``"edge.cup-tabletop.int8"`` → ``("edge", "cup-tabletop.int8")``; a bare tag gives ``(None, tag)``."""
    head, _, rest = str(name).partition(".")
    if rest and _key(rest).removesuffix(".int8") in {_key(t) for t in WEIGHTS}:
        return head, rest
    return None, str(name)


def full_name(tag: str) -> str:
    """The ``arch.tag`` name of a shipped model's tag, e.g. ``cup-tabletop.int8`` → ``edge.cup-tabletop.int8``."""
    base = tag.removesuffix(".int8")
    return f"{WEIGHTS[base]}.{tag}" if base in WEIGHTS else tag


def resolve_model(name_or_path) -> pathlib.Path:
    """A model file path from a path or a shipped model's name: ``arch.tag`` (``edge.cup-tabletop``) or the tag alone
    (``cup-tabletop``); case-, '-'/'_'- and '.onnx'-insensitive.

    Raises ``ModelFormatError`` naming the shipped models when neither a file nor a known name matches.
    """
    from equipose.core.errors import ModelFormatError
    path = pathlib.Path(name_or_path)
    if path.is_file():
        fp32 = fp32_path_for(path)
        return ensure_int8(fp32) if fp32 is not None and fp32.is_file() else path
    arch, tag = split_name(str(name_or_path))
    key = _key(tag)
    if arch is not None:
        base = _key(tag).removesuffix(".int8").replace("_", "-")
        shipped = WEIGHTS.get(base)
        if shipped != arch.lower():
            raise ModelFormatError(f"model {str(name_or_path)!r}: {base} ships with preset {shipped!r} "
                                   f"({shipped}.{base}), not {arch!r}")
    for p in _fp32_files():
        if _key(p.name) == key:
            return p
        if _key(int8_path_for(p).name) == key:
            return ensure_int8(p)
    raise ModelFormatError(f"model {str(name_or_path)!r} is neither a file nor a shipped model; shipped: "
                           f"{', '.join(model_names()) or 'none'} (see 'equipose models')")


def resolve_model_file(model_path) -> pathlib.Path:
    """A shipped model's name (``equipose models``) or the path of an ``.onnx`` file → an existing file's path.

    Raises ``ModelFormatError`` for a non-path argument, a directory or a missing file.
    """
    from equipose.core.errors import ModelFormatError
    if not isinstance(model_path, (str, os.PathLike)):
        raise ModelFormatError(f"model must be a shipped model's name or the path of an equipose .onnx file, got "
                               f"{type(model_path).__name__} (see 'equipose models')")
    path = pathlib.Path(model_path)
    if not path.exists() and isinstance(model_path, str) and "/" not in model_path and "\\" not in model_path:
        path = resolve_model(model_path)                    # a shipped model's name (an int8 copy made current there)
    elif (fp32 := fp32_path_for(path)) is not None and fp32.is_file():      # an int8 copy: built / kept current
        path = ensure_int8(fp32)
    if path.is_dir():
        raise ModelFormatError(f"{str(path)!r} is a directory; pass the path of an equipose .onnx file in it")
    if not path.is_file():
        raise ModelFormatError(f"model file {str(path)!r} does not exist; pass the path of an equipose .onnx model "
                               "(the demo model is equipose.models.demo_model_path())")
    return path


def model_card(path) -> dict:
    """One model's listing (JSON-ready): name, id (``arch.tag``), path, category, mode, preset, precision, size,
    symmetry (the network's) and result_symmetry (what its results carry), test metrics, training.

    Reads the metadata only (the onnx protobuf's metadata map, ``equipose.core.model_file``; no onnxruntime session,
    no inference). ``precision`` comes from the metadata key (older files: from the ``.int8`` name suffix).
    """
    from equipose.core.model_file import read_metadata
    from equipose.core.symmetry import parse_symmetry
    path = pathlib.Path(path)
    meta = read_metadata(path)
    parse_symmetry(str(meta["symmetry"]))
    precision = meta.get("precision") or ("int8" if path.name.endswith(".int8.onnx") else "fp32")
    training = meta.get("training") or {}
    name = path.name.removesuffix(".onnx").replace("_", "-")
    return {"name": name, "id": full_name(name), "path": str(path),
            "category": str(meta["category"]), "mode": "partial" if meta["partial"] else "complete",
            "preset": meta["preset"], "precision": precision, "size_mb": round(path.stat().st_size / 1e6, 3),
            "num_points": int(meta["num_points"]), "scale_m_per_unit": float(meta["scale"]),
            "symmetry": str(meta["symmetry"]), "result_symmetry": result_symmetry(meta),
            "random_init": bool(meta["random_init"]), "metrics": meta.get("metrics") or {}, "training": training}


def result_symmetry(meta: dict) -> str:
    """The symmetry a model's results carry: its category's, except where a stage settles the free angle (a mug's
    handle stage makes the pose full 6D: "none (handle)")."""
    return "none (handle)" if meta.get("handle") is not None else str(meta["symmetry"])


def model_cards(paths=None) -> list:
    """``model_card`` of each path (default: every shipped model)."""
    return [model_card(p) for p in (paths or list_models())]
