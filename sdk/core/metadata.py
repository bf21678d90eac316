"""The equipose ONNX metadata contract: keys, encoding (strings; JSON where structured) and validation.

Written by ``equipose.export`` into ``ModelProto.metadata_props``; read by the SDK through onnxruntime's
``custom_metadata_map``. Torch-free.

Keys (all values are strings):
    equipose_format         format version, currently "4" for quotient presets (the graph takes each layer's kernel
                            weights summed per kernel class and its gathered feature rows as inputs,
                            ``equipose.core.kernel_weights``, and outputs no hypothesis scores) and "2" for the
                            others (the kNN neighbourhoods as inputs); the runtime computes the inputs and the scores
                            (``equipose.runtime.session.GraphIO``); "3" files (the kernel weights themselves) and "1"
                            files, whose graphs compute all of it, still read
    equipose_version        package version that wrote the file
    category                e.g. "airplane", "mug"
    preset                  preset name (``equipose.core.presets``)
    model_config            JSON of the preset's ``ModelConfig.to_dict()``
    num_points              N, the model's input point count
    num_canonical_points    M
    scale                   metres per model unit (SDK divides metric points by it)
    partial                 "true" | "false"
    symmetry                "none" | "continuous:<x|y|z>" | "discrete:<spec>"
    calibration_rotation    JSON 3×3: δR, learned frame → category frame (R_cat = R_pred · δRᵀ)
    calibration_translation JSON 3: δt in model units (t_cat = t_pred − R_cat · δt)
    anchors                 JSON 60×4: the group rotations as (w, x, y, z), in hypothesis order
    random_init             "true" for random-weight models (tests, benchmarks)
    training                JSON: training data summary (dataset, mode, steps, ...)
    metrics                 JSON: metrics on the test split ({} if none)
Optional keys (absent in older files): ``precision`` "fp32" | "int8" (weights of the graph's MatMul/Gemm);
``refine_calibration`` JSON {k, iters, copies, rotation 3×3, translation 3, ...}: the calibration for the SDK's ICP
re-scoring of the k best hypotheses with ``copies`` rotated input copies per object (absent: 1; ``equipose calibrate
--model M --refine K --copies C``) and, for partial-view models, ``visibility`` (absent/null: off; the exponent of the
view-aware re-scoring, ``equipose.runtime.visibility``, ``--visibility E``) and ``polish`` (absent: 0; ICP
iterations on the selected pose, ``--polish N``) and ``densify`` (absent: 0; the ICP template gains the midpoints to
each point's N nearest neighbours, ``equipose.runtime.template``, ``--densify N``); ``handle`` JSON {"direction": 3}:
the unit handle direction in the category frame, for categories whose pose includes a handle (``mug``: +x); the SDK
then reports whether the handle was seen (``PoseResult.handle_visible``); ``shape_prior`` "cylinder": the SDK takes the
symmetry axis from the observed normals (cans and tins, whose two ends look alike: the axis has no sign,
``equipose.runtime.cylinder``), "open_cylinder": the same for a body with one open end (cups and mugs: the axis
keeps its sign); ``flip_templates`` JSON
{"points": T×M×3, "axes": ["z"], "source": str}: category-frame shapes (model units) that settle half-turn flips
about those axes (``equipose.runtime.flip``); ``rest_facet`` JSON {"tolerance_deg": float}: complete-shape models read
"up" off the cloud's resting hull face (``equipose.runtime.rest_facet``); ``frame_priors`` JSON {"steps": ["rest", "mirror",
"footprint"] (some, in order), "mirror_axis": "x"|"y"|"z", "max_deg": float}: complete-shape models turn the pose onto
the cloud's mirror plane and footprint rectangle (``equipose.runtime.frame_priors``); ``turn_classifier`` JSON
{"axes": ["x", "y", "z"], "margin": float, "ambiguous_margin": float, "point": [layer, ...], "head": [layer, ...],
"source": {...}} with each layer {"shape": [out, in], "weight": base64 float32 little-endian (out·in),
"bias": base64 float32 (out)}: a PointNet scorer of the view's canonical points that settles half turns about those
axes (``equipose.runtime.turn_classifier``); ``confidence_calibration`` JSON {"features": [name, ...] (some of
``CONFIDENCE_FEATURES``), "weights": [float, ...], "bias": float, "definition": str, ...}: the logistic model that turns
a result's evidence into the chance that its pose is right (``equipose.runtime.stages.confidence``).
"""
from __future__ import annotations

import base64
import json
import math

import numpy as np

from equipose.core import icosahedral
from equipose.core.errors import MetadataError, ModelVersionError

__all__ = ["FORMAT_VERSION", "READABLE_FORMATS", "REQUIRED_KEYS", "FRAME_PRIOR_STEPS", "CONFIDENCE_FEATURES", "MAX_COPIES", "MAX_POLISH", "MAX_DENSIFY",
           "encode_metadata", "decode_metadata", "encode_turn_classifier", "flush_negligible", "float_entry"]

FORMAT_VERSION = 4                                         # 2 for presets without quotient (vertex) layers
READABLE_FORMATS = (1, 2, 3, 4)                            # 1: kNN and hypothesis scores inside the graph
FRAME_PRIOR_STEPS = ("rest", "mirror", "footprint")       # equipose.runtime.frame_priors
CONFIDENCE_FEATURES = ("margin", "flip_margin", "residual", "outliers", "coverage", "occlusion", "log_points",
                       "ambiguous", "up_given", "handle_seen", "handle_share", "plane_tilt",
                       "handle_fit_share", "handle_fit_mass", "plane_float", "plane_sink", "plane_rest",
                       "axis_ratio", "top_cap", "bottom_cap", "top_taper", "own_axis_turn", "plane_lying")
                                                           # equipose.runtime.stages.confidence
MAX_COPIES = 64                                            # refine_calibration copies; equipose.runtime.copies
MAX_POLISH = 200                                           # refine_calibration polish; equipose.runtime.refine
MAX_DENSIFY = 16                                           # refine_calibration densify; equipose.runtime.template
REQUIRED_KEYS = ("equipose_format", "equipose_version", "category", "preset", "model_config", "num_points",
                 "num_canonical_points", "scale", "partial", "symmetry", "calibration_rotation",
                 "calibration_translation", "anchors", "random_init", "training", "metrics")


def encode_metadata(*, category: str, preset: str, model_config: dict, num_points: int, num_canonical_points: int,
                    scale: float, partial: bool, symmetry: str = "none", calibration_rotation=None,
                    calibration_translation=None, random_init: bool = False, training: dict | None = None,
                    metrics: dict | None = None, handle=None, shape_prior: str | None = None) -> dict:
    """Build the ``{key: str}`` metadata dict of an equipose model. ``handle``: [3] handle direction (or None)."""
    from equipose import __version__
    R = np.eye(3) if calibration_rotation is None else np.asarray(calibration_rotation, dtype=float)
    t = np.zeros(3) if calibration_translation is None else np.asarray(calibration_translation, dtype=float)
    _check_symmetry(symmetry)
    return {
        "equipose_format": str(FORMAT_VERSION),
        "equipose_version": __version__,
        "category": str(category),
        "preset": str(preset),
        "model_config": json.dumps(model_config),
        "num_points": str(int(num_points)),
        "num_canonical_points": str(int(num_canonical_points)),
        "scale": repr(float(scale)),
        "partial": "true" if partial else "false",
        "symmetry": symmetry,
        "calibration_rotation": json.dumps(R.reshape(3, 3).tolist()),
        "calibration_translation": json.dumps(t.reshape(3).tolist()),
        "anchors": json.dumps(np.round(icosahedral.ANCHOR_QUATERNIONS, 9).tolist()),
        "random_init": "true" if random_init else "false",
        "training": json.dumps(training or {}),
        "metrics": json.dumps(metrics or {}),
        "precision": "fp32",
    } | ({} if handle is None else {"handle": json.dumps({"direction": _unit_handle(handle, "handle").tolist()})}) \
      | ({} if shape_prior is None else {"shape_prior": _check_shape_prior(shape_prior, "shape_prior")})


def float_entry(text, name: str, key: str, source: str, hint: str) -> dict | None:
    """A JSON metadata entry ``name`` (string or dict; empty: None) → its dict with ``key`` read as a float. Raises
    ``MetadataError`` naming the command that writes it (``hint``) when it is not JSON or ``key`` is missing."""
    if not text:
        return None
    try:
        d = json.loads(text) if isinstance(text, str) else dict(text)
        value = float(d[key])
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed {name} metadata ({e}); re-run '{hint}'") from None
    return {**d, key: value}


SHAPE_PRIORS = ("cylinder", "open_cylinder")


def _check_shape_prior(v, source: str) -> str:
    if v not in SHAPE_PRIORS:
        raise MetadataError(f"{source}: shape_prior must be one of {', '.join(SHAPE_PRIORS)}, got {v!r}")
    return v


def _flip_templates(text, source: str):
    """``flip_templates`` metadata → {"points": [T, M, 3] float64 (model units, category frame), "axes": [str]}."""
    if not text:
        return None
    try:
        d = json.loads(text)
        pts, axes = np.asarray(d["points"], np.float64), [str(a) for a in d.get("axes", ["z"])]
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed flip_templates metadata ({e}); re-add them") from None
    if pts.ndim != 3 or pts.shape[0] < 1 or pts.shape[1] < 16 or pts.shape[2] != 3 or not np.all(np.isfinite(pts)):
        raise MetadataError(f"{source}: flip_templates must be T×M×3 finite points (M ≥ 16), got {pts.shape}")
    if not axes or any(a not in ("x", "y", "z") for a in axes):
        raise MetadataError(f"{source}: flip_templates axes must be some of x, y, z, got {axes}")
    return {"points": pts, "axes": axes}


def flush_negligible(a, rel: float = 1e-12) -> np.ndarray:
    """``a`` as float32 with the values below ``rel`` × its largest magnitude set to 0 (subnormals always). A product
    with a subnormal operand or result takes ~100× longer on x86 CPUs that do not flush them (onnxruntime's and
    OpenBLAS's kernels run without flush-to-zero), and trained weights decayed to 1e-38 give such products with any
    activation; their share of a sum is below float32's resolution (6e-8) by orders of magnitude."""
    x = np.array(a, np.float32)
    top = float(np.abs(x).max()) if x.size else 0.0
    x[np.abs(x) < max(np.finfo(np.float32).tiny, rel * top)] = 0.0
    return x


def encode_turn_classifier(point: list, head: list, axes, margin: float, ambiguous_margin: float,
                           source: dict | None = None) -> str:
    """``turn_classifier`` metadata value from layer lists [(W [out, in], b [out]), ...] (float32, ``x Wᵀ + b``)."""
    def layer(W, b):
        W, b = flush_negligible(W).astype("<f4"), flush_negligible(b).astype("<f4")
        return {"shape": list(W.shape), "weight": base64.b64encode(W.tobytes()).decode("ascii"),
                "bias": base64.b64encode(b.tobytes()).decode("ascii")}
    return json.dumps({"axes": list(axes), "margin": float(margin), "ambiguous_margin": float(ambiguous_margin),
                       "point": [layer(W, b) for W, b in point], "head": [layer(W, b) for W, b in head],
                       "source": source or {}})


def _turn_classifier(text, source: str):
    """``turn_classifier`` metadata → {"axes", "margin", "ambiguous_margin", "weights": {"point", "head"}} or None."""
    if not text:
        return None
    try:
        d = json.loads(text)
        axes = [str(a) for a in d["axes"]]
        weights = {}
        for part in ("point", "head"):
            layers = []
            for L in d[part]:
                o, i = (int(v) for v in L["shape"])
                W = np.frombuffer(base64.b64decode(L["weight"]), "<f4").reshape(o, i)
                b = np.frombuffer(base64.b64decode(L["bias"]), "<f4").reshape(o)
                layers.append((flush_negligible(W), flush_negligible(b)))
            weights[part] = layers
        margin, amb = float(d["margin"]), float(d["ambiguous_margin"])
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed turn_classifier metadata ({e}); re-add it "
                            "(python -m equipose.train.turn_classifier)") from None
    if not axes or any(a not in ("x", "y", "z") for a in axes):
        raise MetadataError(f"{source}: turn_classifier axes must be some of x, y, z, got {axes}")
    pt, hd = weights["point"], weights["head"]
    chain = pt + hd

    def chains(layers, first_in: int) -> bool:                # each layer's input width is the previous one's output
        return [W.shape[1] for W, _ in layers] == [first_in] + [W.shape[0] for W, _ in layers[:-1]]

    if not pt or not hd or not chains(pt, 3) or not chains(hd, 2 * pt[-1][0].shape[0]) or hd[-1][0].shape[0] != 1:
        raise MetadataError(f"{source}: turn_classifier layer shapes do not chain (point 3 → F, head 2F → 1): "
                            f"{[W.shape for W, _ in chain]}")
    if not all(np.all(np.isfinite(W)) and np.all(np.isfinite(b)) for W, b in chain) or \
            not (math.isfinite(margin) and math.isfinite(amb)):
        raise MetadataError(f"{source}: turn_classifier weights or margins are not finite")
    return {"axes": axes, "margin": margin, "ambiguous_margin": amb, "weights": weights,
            "source": d.get("source", {})}


def _rest_facet(text, source: str):
    """``rest_facet`` metadata → {"tolerance_deg": float in (0, 90)} or None."""
    if not text:
        return None
    try:
        tol = float(json.loads(text)["tolerance_deg"])
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed rest_facet metadata ({e})") from None
    if not 0.0 < tol < 90.0:
        raise MetadataError(f"{source}: rest_facet tolerance_deg must be in (0, 90), got {tol}")
    return {"tolerance_deg": tol}


def _confidence_calibration(text, source: str):
    """``confidence_calibration`` metadata → {"features": tuple, "weights" [F], "bias": float, ...} or None."""
    if not text:
        return None
    try:
        d = json.loads(text)
        feats, w, b = tuple(str(f) for f in d["features"]), np.asarray(d["weights"], np.float64), float(d["bias"])
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed confidence_calibration metadata ({e}); re-run "
                            "'python -m equipose.train.evaluation.confidence --model ... --write'") from None
    unknown = [f for f in feats if f not in CONFIDENCE_FEATURES]
    if unknown or w.shape != (len(feats),) or not (np.all(np.isfinite(w)) and math.isfinite(b)):
        raise MetadataError(f"{source}: confidence_calibration needs finite weights, one per feature of "
                            f"{', '.join(CONFIDENCE_FEATURES)}; got features {list(feats)} and weights {w.tolist()}")
    return {**d, "features": feats, "weights": w, "bias": b}


def _frame_priors(text, source: str):
    """``frame_priors`` metadata → {"steps": [str], "mirror_axis": str | None, "max_deg": float} or None."""
    if not text:
        return None
    try:
        d = json.loads(text)
        steps, axis, max_deg = [str(x) for x in d["steps"]], d.get("mirror_axis"), float(d.get("max_deg", 20.0))
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed frame_priors metadata ({e}); re-run "
                            "'python -m equipose.export.frame_priors'") from None
    if not steps or any(x not in FRAME_PRIOR_STEPS for x in steps):
        raise MetadataError(f"{source}: frame_priors steps must be a non-empty list of 'rest' / 'mirror' / "
                            f"'footprint', got {steps}")
    if "mirror" in steps and axis not in ("x", "y", "z"):
        raise MetadataError(f"{source}: frame_priors with a mirror step needs mirror_axis x, y or z, got {axis!r}")
    if not 0.0 < max_deg <= 45.0:
        raise MetadataError(f"{source}: frame_priors max_deg must be in (0, 45], got {max_deg}")
    return {"steps": steps, "mirror_axis": axis, "max_deg": max_deg}


def _unit_handle(v, source: str) -> np.ndarray:
    d = np.asarray(v, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(d))
    if not (np.all(np.isfinite(d)) and n > 0 and abs(d[2]) < 1e-6 * n):
        raise MetadataError(f"{source}: handle direction must be a finite horizontal vector (z = 0), got {d.tolist()}")
    return d / n


def _check_symmetry(s: str):
    if s == "none" or (s.startswith("continuous:") and s.split(":", 1)[1] in ("x", "y", "z")) or s.startswith("discrete:"):
        return
    raise MetadataError(f"symmetry must be 'none', 'continuous:<x|y|z>' or 'discrete:<spec>', got {s!r}")


def decode_metadata(props: dict, source: str = "model") -> dict:
    """Validate and parse a ``{key: str}`` map into python values. Raises ``ModelVersionError`` / ``MetadataError``.

    Returns a dict with the same keys: ints for counts, float scale, bools, numpy arrays for the calibration
    (``calibration_rotation`` [3, 3], ``calibration_translation`` [3]) and ``anchors`` [60, 4], dicts for JSON,
    ``refine_calibration`` as a dict with arrays (None when absent).
    """
    if "equipose_format" not in props:
        raise MetadataError(f"{source} is an ONNX model but not an equipose model (no 'equipose_format' metadata); "
                            "export it with 'equipose export'")
    try:
        version = int(props["equipose_format"])
    except ValueError:
        raise MetadataError(f"{source}: equipose_format {props['equipose_format']!r} is not an integer") from None
    if version not in READABLE_FORMATS:
        raise ModelVersionError(f"{source} has equipose metadata format {version}, this SDK reads formats "
                                f"{', '.join(map(str, READABLE_FORMATS))}; re-export the model with this equipose "
                                "version or upgrade equipose")
    missing = [k for k in REQUIRED_KEYS if k not in props]
    if missing:
        raise MetadataError(f"{source} lacks required metadata key(s) {', '.join(missing)}; re-export it with "
                            "'equipose export'")
    try:
        out = dict(props)
        for k in ("num_points", "num_canonical_points"):
            out[k] = int(props[k])
        out["equipose_format"] = version
        out["scale"] = float(props["scale"])
        for k in ("partial", "random_init"):
            if props[k] not in ("true", "false"):
                raise ValueError(f"{k} must be 'true' or 'false'")
            out[k] = props[k] == "true"
        for k in ("model_config", "training", "metrics"):
            out[k] = json.loads(props[k])
        out["calibration_rotation"] = np.asarray(json.loads(props["calibration_rotation"]), dtype=np.float64).reshape(3, 3)
        out["calibration_translation"] = np.asarray(json.loads(props["calibration_translation"]), dtype=np.float64).reshape(3)
        out["anchors"] = np.asarray(json.loads(props["anchors"]), dtype=np.float64).reshape(icosahedral.NUM_ROTATIONS, 4)
    except (ValueError, TypeError, json.JSONDecodeError) as e:
        raise MetadataError(f"{source}: malformed equipose metadata ({e}); re-export the model") from None
    try:
        rc = json.loads(props["refine_calibration"]) if props.get("refine_calibration") else None
        out["refine_calibration"] = None if not rc else {
            "k": int(rc["k"]), "iters": int(rc["iters"]), "copies": int(rc.get("copies", 1)),
            "rotation": np.asarray(rc["rotation"], dtype=np.float64).reshape(3, 3),
            "translation": np.asarray(rc["translation"], dtype=np.float64).reshape(3),
            "visibility": None if rc.get("visibility") is None else float(rc["visibility"]),
            "polish": int(rc.get("polish", 0)), "densify": int(rc.get("densify", 0))}
        if rc and not 1 <= out["refine_calibration"]["copies"] <= MAX_COPIES:
            raise ValueError(f"copies must be in 1..{MAX_COPIES}, got {out['refine_calibration']['copies']}")
        if rc and rc.get("visibility") is not None and not -3 <= float(rc["visibility"]) <= 6:
            raise ValueError(f"visibility must be an exponent in -3..6, got {rc['visibility']}")
        for key, top, unit in (("polish", MAX_POLISH, "ICP iterations"), ("densify", MAX_DENSIFY, "neighbours")):
            if rc and not 0 <= out["refine_calibration"][key] <= top:
                raise ValueError(f"{key} must be in 0..{top} {unit}, got {out['refine_calibration'][key]}")
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed refine_calibration metadata ({e}); re-run 'equipose calibrate "
                            "--model'") from None
    try:
        out["handle"] = _unit_handle(json.loads(props["handle"])["direction"], source) if props.get("handle") else None
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed handle metadata ({e}); re-export the model") from None
    out["shape_prior"] = _check_shape_prior(props["shape_prior"], source) if props.get("shape_prior") else None
    out["flip_templates"] = _flip_templates(props.get("flip_templates"), source)
    out["rest_facet"] = _rest_facet(props.get("rest_facet"), source)
    out["turn_classifier"] = _turn_classifier(props.get("turn_classifier"), source)
    out["frame_priors"] = _frame_priors(props.get("frame_priors"), source)
    out["confidence_calibration"] = _confidence_calibration(props.get("confidence_calibration"), source)
    _check_symmetry(out["symmetry"])
    if not (math.isfinite(out["scale"]) and out["scale"] > 0):
        raise MetadataError(f"{source}: scale must be positive, got {out['scale']}")
    rotations = [("calibration_rotation", out["calibration_rotation"], out["calibration_translation"])]
    if out["refine_calibration"]:
        rc = out["refine_calibration"]
        rotations.append(("refine_calibration.rotation", rc["rotation"], rc["translation"]))
    for key, R, t in rotations:
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t)) and np.allclose(R @ R.T, np.eye(3), atol=1e-4)
                and np.linalg.det(R) > 0):
            raise MetadataError(f"{source}: {key} is not a rotation matrix (or its translation is not finite): "
                                f"{np.round(R, 4).tolist()}; re-run 'equipose calibrate --model' or re-export the model")
    return out
