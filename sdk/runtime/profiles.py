"""Named profiles: points on the speed / accuracy curve of every model, as stage options (timm-style registry).

``PoseEstimator(M, profile=P)`` (CLI ``--profile``): ``"accurate"`` runs every stage with the settings the model
file was calibrated for; ``"default"`` the fastest settings measured to keep each model's accuracy within noise of
``"accurate"``; ``"fast"`` the network's own pose (no ICP) plus the stages that define what a result means (the
turn classifier, the cylinder axis, the handle). Each profile holds options for all models
(``"*"``) and per shipped model (its name); measured accuracy and latency per model: docs/benchmarks.md. A ``points``
cap on the crop (polish, frame priors) at the size of the test sets' clouds (2048 points partial, 1024 complete) keeps
the accuracy measured on them and bounds the cost on the larger crops of a camera frame (up to 4096 points).
Options explicitly given to ``PoseEstimator`` (``refine=``, ``copies=``, ``stages=`` ...) win over the profile.
"""
from __future__ import annotations

import pathlib

from equipose.core.errors import ConfigError

__all__ = ["PROFILES", "register_profile", "profile_options", "merge_stage_options"]

FAST = {"copies": False, "rescore": False, "view": False, "polish": False, "rest_facet": False,
        "frame_priors": False, "flip": False}                               # the network's pose + cheap stages

PROFILES: dict = {
    "accurate": {"*": {}},
    "default": {"*": {},                             # per model: settings measured within noise of accurate
                # (docs/benchmarks.md, v0.24, v0.28, v0.29, v0.32, v0.33, v0.43: full test sets, fp32 and int8)
                "airplane-complete": {"flip": {"templates": 4}, "rescore": {"k": 4}},
                "airplane-partial": {"flip": {"templates": 2}, "turn": {"points": 128}},
                "car-complete": {"upright": {"points": 64}, "rescore": {"iters": 8, "k": 4},
                                 "frame_priors": {"mirror_iters": 3, "points": 1024, "mirror_coarse": 3}},
                "chair-complete": {"frame_priors": {"points": 1024, "mirror_coarse": 3},
                                   "rescore": {"k": 4, "points": 128}},
                "sofa-complete": {"rescore": {"iters": 10, "k": 3}, "frame_priors": {"points": 1024},
                                  "upright": {"points": 64}},
                "bottle-complete": {"rescore": {"iters": 15}},
                "bottle-partial": {"rescore": {"iters": 15, "k": 4}},
                "car-partial": {"polish": {"points": 2048}, "flip": {"templates": 2}},
                "cup-tabletop": {"rescore": {"k": 4}},
                "can-tabletop": {"rescore": {"k": 4}},
                "bowl-tabletop": {"rescore": {"k": 4}},
                "sofa-partial": {"polish": {"points": 1024}, "rescore": {"points": 128, "densify": 4},
                                 "copies": {"count": 4}, "turn": {"points": 128}},   # v0.38: 4 copies, denser template
                "chair-partial": {"view": {"k": 2}, "rescore": {"points": 128, "iters": 20},
                                  "polish": {"iters": 20, "tol": 1e-3}}},   # v0.33's view k; v0.37's re-scoring
                                                                             # and polish; v0.45's polish tol
    "fast": {"*": FAST},
}


def register_profile(name: str, options: dict) -> None:
    """Add or replace a profile: {"*": {stage: options}, "<model name>": {stage: options}}."""
    if not isinstance(options, dict) or not all(isinstance(v, dict) for v in options.values()):
        raise ConfigError(f"profile {name!r}: options must be {{model name or '*': {{stage: options}}}}")
    PROFILES[name] = options


def _model_name(path) -> str:
    stem = pathlib.Path(path).name
    for suffix in (".onnx", ".int8"):
        stem = stem[: -len(suffix)] if stem.endswith(suffix) else stem
    return stem


def profile_options(profile: str, path) -> dict:
    """{stage: options} of ``profile`` for the model file at ``path`` (its name picks the per-model entry)."""
    if profile not in PROFILES:
        raise ConfigError(f"unknown profile {profile!r}; profiles: {', '.join(PROFILES)}")
    table = PROFILES[profile]
    return merge_stage_options(table.get("*", {}), table.get(_model_name(path), {}))


def merge_stage_options(*layers) -> dict:
    """Stage options merged left to right: a later layer's value wins unless it is "auto" (or None where "auto"
    is the default); a stage set to False is off, True or a dict turns it back on."""
    out: dict = {}
    for layer in layers:
        for stage, opts in (layer or {}).items():
            if opts is False or opts is True:
                out[stage] = opts if opts is False else {}
                continue
            if not isinstance(opts, dict):
                raise ConfigError(f"stage {stage!r}: options must be a dict, True or False, got {opts!r}")
            base = out.get(stage)
            explicit = {k: v for k, v in opts.items() if not (isinstance(v, str) and v == "auto")}
            if base is False:
                if explicit:
                    out[stage] = explicit
                continue
            out[stage] = {**(base or {}), **explicit}
    return out
