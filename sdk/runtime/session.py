"""onnxruntime sessions of equipose models: opening, I/O checks, metadata without a full estimator.

Convention: an equipose model takes ``points`` [batch, N, 3] float32 (model units, FPS-ordered) and outputs
``GRAPH_OUTPUTS``. Format-2 graphs also take the points' neighbourhoods and leave the hypothesis scores out; format-3
graphs take each layer's kernel weights and gathered feature rows instead of the neighbourhoods
(``equipose.core.kernel_weights``), format-4 graphs the kernel weights summed per kernel class; the runtime computes
all of these (``GraphIO``), so a run always yields the four ``OUTPUT_NAMES``. Format-1 graphs take only the points
and compute the rest themselves. The equipose metadata lives in the ONNX custom metadata map.
"""
from __future__ import annotations

import json
import pathlib

import numpy as np

from equipose.core.errors import ModelFormatError
from equipose.core.kernel_weights import (CLASS_PREFIX, ROWS_PREFIX, WEIGHTS_PREFIX, class_name, kernel_input_names,
                                          kernel_inputs)
from equipose.core.model_file import read_metadata  # noqa: F401  (re-exported: reading metadata needs no session)
from equipose.core.neighbourhoods import INPUT_PREFIX, input_name, neighbourhood_specs, neighbourhoods
from equipose.core.presets import ModelConfig
from equipose.core.scores import hypothesis_scores

__all__ = ["INPUT_NAME", "GRAPH_OUTPUTS", "SCORES", "OUTPUT_NAMES", "RUN_CHUNK", "open_session", "session_options",
           "check_io", "read_metadata", "run_in_chunks", "GraphIO"]

INPUT_NAME = "points"
GRAPH_OUTPUTS = ("canonical_shape", "hypothesis_rotations", "hypothesis_translations")   # every model's graph
SCORES = "hypothesis_scores"                                                               # in format-1 graphs only
OUTPUT_NAMES = GRAPH_OUTPUTS + (SCORES,)
RUN_CHUNK = 32              # network inputs per onnxruntime run: larger batches (objects × copies) run in chunks, which
                            # bounds memory (an edge model needs ≈ 8 MB of activations per input)


def run_in_chunks(run, x, chunk: int = RUN_CHUNK) -> dict:
    """``run`` (inputs [B, N, 3] → the 4 output arrays) over ``x`` in pieces of at most ``chunk``, outputs joined."""
    if len(x) <= chunk:
        return run(x)
    parts = [run(x[i:i + chunk]) for i in range(0, len(x), chunk)]
    return {k: np.concatenate([p[k] for p in parts]) for k in OUTPUT_NAMES}


def session_options(threads: int | None):
    """onnxruntime ``SessionOptions`` for the SDK's sessions: ``threads`` intra-op threads (None: onnxruntime's
    default), one inter-op thread, no busy-waiting workers between runs (they would steal the cores from the crop /
    FPS of the next frame)."""
    import onnxruntime as ort

    opts = ort.SessionOptions()
    if threads:
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return opts


def open_session(path, threads: int | None):
    """A CPU ``InferenceSession`` of ``path`` with ``threads`` intra-op threads (None: onnxruntime's default).

    Raises ``ModelFormatError`` when onnxruntime cannot load the file.
    """
    import onnxruntime as ort

    path = pathlib.Path(path)
    try:
        return ort.InferenceSession(str(path), sess_options=session_options(threads),
                                    providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own (pybind) exception types for unreadable files
        raise ModelFormatError(f"{path.name} is not a loadable ONNX model ({type(e).__name__}: "
                               f"{str(e).splitlines()[0][:200]}); pass an .onnx file written by 'equipose export'") from None


def check_io(session, name: str, num_points: int):
    """Check the session's inputs/outputs against the equipose layout; returns the static batch size (or None)."""
    ins = session.get_inputs()
    outs = {o.name: o for o in session.get_outputs()}
    if not ins or ins[0].name != INPUT_NAME or \
            any(not i.name.startswith((INPUT_PREFIX, WEIGHTS_PREFIX, CLASS_PREFIX, ROWS_PREFIX)) for i in ins[1:]):
        raise ModelFormatError(f"{name}: expected the input {INPUT_NAME!r} (then only {INPUT_PREFIX}<support>, "
                               f"{WEIGHTS_PREFIX}<layer>, {CLASS_PREFIX}<layer> or {ROWS_PREFIX}<layer> inputs), got "
                               f"{[i.name for i in ins]}; not an equipose model")
    missing = [o for o in GRAPH_OUTPUTS if o not in outs]
    if missing:
        raise ModelFormatError(f"{name}: outputs {missing} missing (has {sorted(outs)}); not an equipose model")
    shape = ins[0].shape                                                        # [batch, N, 3]
    if len(shape) != 3 or shape[2] != 3 or (isinstance(shape[1], int) and shape[1] != num_points):
        raise ModelFormatError(f"{name}: input shape {shape} does not match [batch, {num_points}, 3] "
                               "from its metadata; re-export the model")
    return shape[0] if isinstance(shape[0], int) else None


class GraphIO:
    """What a model's graph takes and gives beyond ``points``, and how the runtime completes it.

    Format 2: the graph takes the neighbourhoods ``neighbours_<support>`` [B, centres, k] int64 as inputs and outputs
    no scores; both are computed here (``equipose.core.neighbourhoods``, ``equipose.core.scores``). Format 3: the
    graph takes each layer's kernel weights and feature rows (``equipose.core.kernel_weights``, from the same
    neighbourhoods) instead; format 4: for some layers the kernel weights summed per kernel class. Format 1: the graph
    computes all of it itself. Built from a session (or any object with ``get_inputs`` / ``get_outputs``) and the
    model's metadata (``partial``, ``model_config``).
    """

    def __init__(self, session, metadata: dict, name: str = "model"):
        cfg = metadata["model_config"]
        cfg = ModelConfig.from_dict(json.loads(cfg) if isinstance(cfg, str) else cfg)
        inputs = [i.name for i in session.get_inputs()][1:]
        specs = {input_name(s): s for s in neighbourhood_specs(cfg.layers)}
        self.layers = cfg.layers
        self.kernel_inputs = any(n.startswith((WEIGHTS_PREFIX, CLASS_PREFIX, ROWS_PREFIX)) for n in inputs)
        self.classes = frozenset(i for i in range(len(cfg.layers)) if class_name(i) in inputs)   # format 4
        if self.kernel_inputs:                                                  # formats 3 and 4
            expected = kernel_input_names(cfg.layers, self.classes)
            if sorted(inputs) != sorted(expected):
                raise ModelFormatError(f"{name}: graph inputs {inputs} are not the kernel inputs of its "
                                       f"{len(cfg.layers)} layers ({expected}); re-export the model")
            self.neighbourhoods = list(specs.values())
        else:
            unknown = sorted(set(inputs) - set(specs))
            if unknown:
                raise ModelFormatError(f"{name}: graph inputs {unknown} match no neighbourhood of its layers "
                                       f"({sorted(specs)}); re-export the model")
            self.neighbourhoods = [specs[n] for n in inputs]                    # in graph-input order
        self.outputs = [o.name for o in session.get_outputs() if o.name in OUTPUT_NAMES]
        partial = metadata["partial"]
        self.partial = partial == "true" if isinstance(partial, str) else bool(partial)
        self.score_points = int(cfg.score_points)

    def feeds(self, x: np.ndarray) -> dict:
        """The graph's inputs for ``x`` [B, N, 3] float32 model units: the points and their neighbourhoods
        (format 2), or the kernel inputs computed from them (formats 3 and 4)."""
        nbh = neighbourhoods(x, self.neighbourhoods)
        return {INPUT_NAME: x, **(kernel_inputs(x, self.layers, nbh, self.classes) if self.kernel_inputs else nbh)}

    def complete(self, outputs: dict, x: np.ndarray) -> dict:
        """The graph's ``outputs`` on ``x`` with ``hypothesis_scores`` [B, 60] added when the graph does not compute
        them: one-directional for partial models, bidirectional for complete ones, from the first
        ``model_config.score_points`` input points (0 = all)."""
        if SCORES in outputs:
            return outputs
        scores = hypothesis_scores(x, outputs["canonical_shape"], outputs["hypothesis_rotations"],
                                   outputs["hypothesis_translations"], bidirectional=not self.partial,
                                   score_points=self.score_points)              # [B, 60]
        return {**outputs, SCORES: scores}

    def run(self, session, x: np.ndarray) -> dict:
        """One run of ``session`` on ``x`` [B, N, 3] float32 model units → the four ``OUTPUT_NAMES``."""
        return self.complete(dict(zip(self.outputs, session.run(self.outputs, self.feeds(x)))), x)
