"""The pose pipeline of one estimator: its model's ordered stages, built once, run on every object.

``Pipeline.build(spec, options, mode)`` asks every registered stage (``equipose.runtime.stage``, in ``STAGE_ORDER``)
whether it applies to the model and with which settings; ``run`` turns one object's network outputs into a
``PoseResult``. ``options``: {stage name: False (off) | {option: value}} merged over the stage's defaults, which
"auto" values resolve from the model file.

Convention: network outputs are the 4 ONNX outputs of a batch (``equipose.runtime.session.OUTPUT_NAMES``); with
rotated copies (stage ``copies``) object b's copies are rows b·K … b·K + K − 1. Results map the category frame to
the camera frame, translation in metres.
"""
from __future__ import annotations

import time

import numpy as np

from equipose.core.errors import ConfigError
from equipose.runtime import stages as _stages  # noqa: F401  (registers the built-in stages)
from equipose.runtime.hypotheses import canonicalise_rotation, parse_symmetry
from equipose.runtime.result import PoseResult
from equipose.runtime.stage import ObjectState, registered_stages

__all__ = ["Pipeline", "MODES"]

MODES = ("category", "instance")
# stage extras that ``PoseResult`` keeps as named fields
RESULT_EXTRAS = ("agreement", "frame_priors", "flip_margin", "turn_margin", "flip_risk", "flip_axis",
                 "handle_visible", "handle_points", "handle_direction_object")


class Pipeline:
    """Ordered, configured stages of one model (see the module docstring). Attribute ``stages``: {name: stage}."""

    def __init__(self, spec, stages: dict, mode: str):
        self.spec, self.stages, self.mode = spec, stages, mode

    @classmethod
    def build(cls, spec, options: dict | None = None, mode: str = "category", context: dict | None = None):
        """Configure every registered stage that applies to ``spec`` (a ``ModelSpec``) in ``mode``.

        ``context``: values stages may need at build time (instance mode: {"instance": InstanceModel}; "threads": the
        estimator's thread budget).
        Raises ``ConfigError`` for options of an unknown stage or an unknown option."""
        if mode not in MODES:
            raise ConfigError(f"pipeline mode must be one of {', '.join(MODES)}, got {mode!r}")
        options = dict(options or {})
        known = registered_stages()
        unknown = [n for n in options if n not in known]
        if unknown:
            raise ConfigError(f"unknown stage(s) {', '.join(map(repr, unknown))}; stages: {', '.join(known)}")
        built: dict = {}
        for name, kind in known.items():
            opt = options.get(name, {})
            if opt is False or mode not in kind.modes:
                continue
            if opt is True:
                opt = {}
            if not isinstance(opt, dict):
                raise ConfigError(f"stage {name!r}: options must be a dict, True or False, got {opt!r}")
            bad = [k for k in opt if k not in kind.options]
            if bad:
                raise ConfigError(f"stage {name!r} has no option(s) {', '.join(map(repr, bad))}; its options: "
                                  f"{', '.join(kind.options) or 'none'}")
            stage = kind.build(spec, {**kind.options, **opt}, {"built": built, "options": options, **(context or {})})
            if stage is not None:
                built[name] = stage
        return cls(spec, built, mode)

    def __contains__(self, name: str) -> bool:
        return name in self.stages

    def get(self, name: str):
        """The configured stage ``name``, or None when it does not run for this model."""
        return self.stages.get(name)

    def info(self) -> list:
        """[{"stage": name, **settings}] in run order (JSON-ready)."""
        return [{"stage": n, **s.describe()} for n, s in self.stages.items()]

    def start(self, outputs: dict, b: int, prep) -> ObjectState:
        """The state of batch item ``b`` straight from the network outputs (copies unpacked by that stage)."""
        copies = self.stages.get("copies")
        if copies is not None:
            return copies.unpack(outputs, b, prep, self.spec.symmetry)
        canon = np.asarray(outputs["canonical_shape"][b], np.float64)          # [M, 3] learned frame
        return ObjectState(prep=prep, R=np.array(outputs["hypothesis_rotations"][b], np.float64),   # [A, 3, 3]
                           t=np.array(outputs["hypothesis_translations"][b], np.float64),           # [A, 3]
                           scores=np.array(outputs["hypothesis_scores"][b], np.float64),            # [A]
                           canonical=canon, template=canon, symmetry=self.spec.symmetry)

    def run(self, outputs: dict, b: int, prep, *, prefer=None, prefer_margin: float = 0.0, up=None,
            category: str = "", top_k: int = 5, crop: dict | None = None, support_plane=None) -> tuple:
        """Batch item ``b`` → (PoseResult with ``timings["stages"]`` = {stage: ms}, pipeline ms). ``crop``: the
        object's crop diagnostics (stages read e.g. the occlusion); ``support_plane``: (unit camera-frame normal,
        offset m) of the support plane under the object, or None (evidence for the confidence)."""
        t0 = time.perf_counter()
        state = self.start(outputs, b, prep)
        state.crop = dict(crop or {})
        state.prefer, state.prefer_margin, state.top_k = prefer, prefer_margin, top_k
        if up is not None:
            state.up, state.up_source = np.asarray(up, np.float64), "given"
        if support_plane is not None:
            state.support_up = np.asarray(support_plane[0], np.float64)
            state.support_offset = float(support_plane[1])
        stage_ms = {}
        for name, stage in self.stages.items():
            t1 = time.perf_counter()
            stage.run(state)
            stage_ms[name] = (time.perf_counter() - t1) * 1e3
        res = self.result(state, category)
        res.timings = {"stages": stage_ms}
        return res, (time.perf_counter() - t0) * 1e3

    def result(self, state: ObjectState, category: str) -> PoseResult:
        """The ``PoseResult`` of a finished state (metres, camera frame)."""
        if state.selection is None or state.rotation is None:
            raise ConfigError(f"{self.spec.name}: the pipeline ({', '.join(self.stages)}) selected no pose; it needs "
                              "a selection stage ('select', 'upright' or 'instance')")
        R, sel = state.rotation, state.selection
        t_m = state.prep.to_metres(state.translation)                           # [3] metres
        canon_obj = state.canonical_category * self.spec.scale                  # [M, 3] category frame, metres
        kind, axis, _ = parse_symmetry(state.symmetry)
        named = {k: state.extras[k] for k in RESULT_EXTRAS if k in state.extras}
        res = PoseResult(
            rotation=R, translation=t_m, score=sel.score, confidence=float(state.confidence),
            ambiguous=bool(state.ambiguous), canonical_shape=canon_obj @ R.T + t_m, canonical_shape_object=canon_obj,
            hypothesis_index=sel.index, top_k=sel.top_k, symmetry=state.symmetry,
            symmetry_axis=None if kind == "none" else R[:, axis].copy(),
            rotation_canonical=canonicalise_rotation(R, state.symmetry), category=category,
            random_init=self.spec.random_init, up=None if state.up is None else state.up.copy(),
            up_source=state.up_source, **named,
            extras={k: v for k, v in state.extras.items() if k not in RESULT_EXTRAS})
        if res.handle_direction_object is not None:
            res.handle_direction = R @ res.handle_direction_object
        return res
