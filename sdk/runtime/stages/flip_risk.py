"""Stage ``flip_risk`` (metadata ``flip_risk``): the chance that the pose is turned by about a half turn (front/back
or upside down, rotation error > 150°), and ``ambiguous`` from it.

The stages before it each judge a half turn on their own and flag the result where their own margin is small: the
selection's scores (``select``, ``view``), the flip templates' fits (``flip``), the turn classifier's logits
(``turn``). On single partial views of cars those flags caught too few of the flips for the share they flagged
(docs/results/models/README.md, v0.44). This stage weighs the same readings together, after the turn classifier:

- ``turn_margin``: the turn classifier's lead of the pose over its best half turn, logits, clipped to
  ±``TURN_CLIP`` (``TURN_CLIP`` without a turn classifier);
- ``flip_margin``: the flip templates' relative margin, else the selection's to its best turned hypothesis, 0..1
  (``flip_margin_reading``; the confidence evidence reads the same);
- ``margin``: the selection's relative margin to the best hypothesis more than 30° away;
- ``agreement``: the share of rotated input copies that agree (1 without copies);
- ``flagged``: whether a stage before flagged the result ``ambiguous`` (0/1).

``flip_risk`` = σ(bias + Σ weight·feature), fitted on rendered views of **training** shapes
(``python -m equipose.train.evaluation.flip_risk``). The result is ``ambiguous`` where ``flip_risk`` reaches the file's
``threshold``, which replaces the flags of the stages before it (each of them stands for a half turn that fits about
as well); the confidence stage after it may still flag a result. Result field ``flip_risk``.

Option ``threshold``: "auto" (the file's; absent: the stage does not run), a probability in (0, 1), or "read"
(leave ``ambiguous`` as the stages set it; report ``flip_risk`` where the file has a model, and the features as the
result extra ``flip_readings``: what the fit reads).

Convention: margins are relative (unitless), logits natural; ``flip_risk`` a probability.
"""
from __future__ import annotations

import json
import math

import numpy as np

from equipose.core.errors import ConfigError, MetadataError
from equipose.core.logistic import entry_probability
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["FlipRiskStage", "FLIP_RISK_FEATURES", "TURN_CLIP", "parse_flip_risk", "flip_margin_reading",
           "flip_features", "flip_risk"]

FLIP_RISK_FEATURES = ("turn_margin", "flip_margin", "margin", "agreement", "flagged")
TURN_CLIP = 10.0                # logits: the turn classifier's lead is clipped to ±this
FIT_COMMAND = "python -m equipose.train.evaluation.flip_risk --model ... --write"


def flip_margin_reading(state: ObjectState) -> float:
    """The flip margin as the stages left it: the flip templates' (``extras["flip_margin"]``), else the selection's
    to its best turned hypothesis; clipped to 0..1, 1 where neither is finite."""
    flip = state.extras.get("flip_margin", getattr(state.selection, "flip_margin", float("nan")))
    return float(np.clip(flip, 0.0, 1.0)) if np.isfinite(flip) else 1.0


def flip_features(turn_margin, flip_margin: float, margin: float, agreement, flagged: bool) -> dict:
    """The stage's features from its readings (``turn_margin`` / ``agreement`` None where the stage did not run)."""
    turn = TURN_CLIP if turn_margin is None else float(np.clip(turn_margin, -TURN_CLIP, TURN_CLIP))
    return {"turn_margin": turn, "flip_margin": float(flip_margin), "margin": float(margin),
            "agreement": 1.0 if agreement is None else float(agreement), "flagged": float(bool(flagged))}


def flip_risk(features: dict, entry: dict) -> float:
    """σ(bias + Σ weight·feature) of a ``flip_risk`` metadata entry (``parse_flip_risk``) on ``features``
    (``equipose.core.logistic.entry_probability``)."""
    return entry_probability(entry, features)


def parse_flip_risk(text, source: str = "model") -> dict | None:
    """``flip_risk`` metadata (JSON string or dict) → {"features": tuple, "weights" [F], "bias", "threshold", ...}
    or None when absent. Raises ``MetadataError`` when malformed."""
    if not text:
        return None
    try:
        d = json.loads(text) if isinstance(text, str) else dict(text)
        feats = tuple(str(f) for f in d["features"])
        w, b, th = np.asarray(d["weights"], np.float64), float(d["bias"]), float(d["threshold"])
    except (ValueError, KeyError, TypeError) as e:
        raise MetadataError(f"{source}: malformed flip_risk metadata ({e}); re-run '{FIT_COMMAND}'") from None
    unknown = [f for f in feats if f not in FLIP_RISK_FEATURES]
    if unknown or w.shape != (len(feats),) or not (np.all(np.isfinite(w)) and math.isfinite(b)) \
            or not 0.0 < th < 1.0:
        raise MetadataError(f"{source}: flip_risk needs finite weights, one per feature of "
                            f"{', '.join(FLIP_RISK_FEATURES)}, and a threshold in (0, 1); got features {list(feats)}, "
                            f"weights {w.tolist()}, threshold {th}; re-run '{FIT_COMMAND}'")
    return {**d, "features": feats, "weights": w, "bias": b, "threshold": th}


@register_stage
class FlipRiskStage(Stage):
    name = "flip_risk"
    metadata_key = "flip_risk"
    after = "turn"
    options = {"threshold": "auto"}

    def __init__(self, entry: dict | None, threshold: float | None):
        self.entry, self.threshold = entry, threshold                           # threshold None: read only

    @classmethod
    def build(cls, spec, options, context):
        entry = parse_flip_risk(spec.get(cls.metadata_key), spec.name)
        th = options["threshold"]
        if isinstance(th, str) and th == "read":
            return cls(entry, None)
        if entry is None:
            if th != "auto":
                raise ConfigError(f"{spec.name} has no flip_risk model to apply a threshold to; fit one "
                                  f"('{FIT_COMMAND}') or leave flip_risk's threshold 'auto'")
            return None
        if isinstance(th, str) and th == "auto":
            return cls(entry, entry["threshold"])
        if isinstance(th, bool) or not isinstance(th, (int, float)) or not 0.0 < th < 1.0:
            raise ConfigError(f"flip_risk threshold must be 'auto', 'read' or a probability in (0, 1) (flag the "
                              f"result ambiguous where its chance of a half turn reaches it), got {th!r}")
        return cls(entry, float(th))

    def describe(self) -> dict:
        return {"features": [] if self.entry is None else list(self.entry["features"]),
                "threshold": self.threshold if self.threshold is not None else "read"}

    def run(self, state: ObjectState) -> None:
        if state.rotation is None:
            return
        f = flip_features(state.extras.get("turn_margin"), flip_margin_reading(state), state.confidence,
                          state.extras.get("agreement"), state.ambiguous)
        if self.threshold is None:
            state.extras["flip_readings"] = f
        if self.entry is None:
            return
        risk = flip_risk(f, self.entry)
        state.extras["flip_risk"] = risk
        if self.threshold is not None:
            state.ambiguous = risk >= self.threshold
