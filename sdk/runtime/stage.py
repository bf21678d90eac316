"""The stage interface of the pose pipeline: what runs on one object between the network outputs and its result.

A stage is one class in one file (``equipose/runtime/stages/``), registered with ``@register_stage``. It declares

- ``name``: how profiles, options and ``PoseEstimator(stages=...)`` refer to it;
- ``metadata_key``: the model metadata key that switches it on (None: it runs for every model of its ``modes``);
- ``options``: its settings with their defaults ("auto" = the model file's value);
- ``build(spec, options, context)``: parses its metadata and options once per estimator and returns the configured stage,
  or None when it does not apply to this model;
- ``run(state)``: works on one object's ``ObjectState`` in place.

Stages run in the order of ``STAGE_ORDER`` (a stage's ``after`` places it there); results carry what a stage adds
in ``state.extras`` (JSON-ready values, keyed by the result field name).

Convention: ``ObjectState`` holds one object in model units and the centred camera frame of its model input
(``PreparedPoints.model_points``): hypotheses map the network's learned frame (after ``calibrate``: the category
frame) into that frame, ``x = R y + t``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from equipose.core.errors import ConfigError, MetadataError
from equipose.core.metadata import float_entry
from equipose.core.normals import point_normals
from equipose.core.opening import top_closure
from equipose.core.order_statistics import selected_percentile

__all__ = ["Stage", "ObjectState", "register_stage", "unregister_stage", "registered_stages", "stage_metadata_keys",
           "STAGE_ORDER", "TOP_PERCENTILE", "NORMAL_NEIGHBOURS", "cloud_points_option", "enabled_option", "entry_options",
           "int_option", "MIN_FIT_POINTS",
           "ShareCapStage", "parse_share_cap", "is_share"]

STAGE_ORDER: list = []          # stage names in run order (registration inserts each after its ``after``)
NORMAL_NEIGHBOURS = 12          # ``ObjectState.normals``: points per PCA normal
TOP_PERCENTILE = 95.0           # ``ObjectState.top_height``: this percentile of the crop points' heights
_REGISTRY: dict = {}


class Stage:
    """Base class of a pipeline stage (see the module docstring)."""

    name: str = ""
    metadata_key: str | None = None
    modes: tuple = ("category",)            # "category" and/or "instance"
    options: dict = {}
    after: str | None = None                # run right after this stage (None: first)

    @classmethod
    def build(cls, spec, options: dict, context: dict):
        """The configured stage for this model, or None when it does not apply. ``options``: this stage's options
        with the user's and the profile's values merged over ``cls.options``; ``context``: {"built": the stages
        configured so far, "options": every stage's options, ...} (see ``Pipeline.build``)."""
        return cls()

    def run(self, state: "ObjectState") -> None:
        raise NotImplementedError

    def describe(self) -> dict:
        """Settings of the configured stage (JSON-ready), for ``PoseEstimator.pipeline_info``."""
        return {}


def is_share(value) -> bool:
    """Whether ``value`` is a share: a finite number in (0, 1] (not a bool)."""
    return not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value) and \
        0.0 < value <= 1.0


def parse_share_cap(text, name: str, source: str, hint: str, key: str = "cap") -> dict | None:
    """A ``{key: share, ...}`` metadata entry ``name`` (JSON string or dict) → the dict with ``key`` a float in
    (0, 1], or None when absent. Raises ``MetadataError`` naming the command that writes it (``hint``) when
    malformed."""
    d = float_entry(text, name, key, source, hint)
    if d is not None and not is_share(d[key]):
        raise MetadataError(f"{source}: {name} {key} must be a share in (0, 1], got {d[key]}")
    return d


class ShareCapStage(Stage):
    """A stage whose metadata entry (``{share_key: share, ...}`` under ``metadata_key``, written by ``fit_command``)
    holds one fitted share, stored as the attribute named ``share_key`` ("cap": a threshold the stage acts beyond,
    otherwise it only reports the reading). Option ``share_key``: "auto" (the file's; absent: the stage does not run),
    a share in (0, 1], or "read" (the share None: report, never act)."""
    options = {"cap": "auto"}
    share_key: str = "cap"                  # the entry's key, the option's name and the attribute holding the share
    share_meaning: str = ""                 # what the share is, for the option's error
    fit_command: str = ""                   # what writes the metadata entry (named in its errors)

    def __init__(self, share: float | None):
        setattr(self, self.share_key, share)                                    # None: read only

    @classmethod
    def parse(cls, text, source: str = "model") -> dict | None:
        """The stage's metadata entry → the dict with ``share_key`` a float in (0, 1], or None
        (``parse_share_cap``)."""
        return parse_share_cap(text, cls.metadata_key, source, cls.fit_command, key=cls.share_key)

    @classmethod
    def build(cls, spec, options, context):
        share = options[cls.share_key]
        if isinstance(share, str) and share == "auto":
            d = cls.parse(spec.get(cls.metadata_key), spec.name)
            return None if d is None else cls(d[cls.share_key])
        if isinstance(share, str) and share == "read":
            return cls(None)
        if not is_share(share):
            meaning = f" ({cls.share_meaning})" if cls.share_meaning else ""
            raise ConfigError(f"{cls.name} {cls.share_key} must be 'auto', 'read' or a share in (0, 1]{meaning}, got "
                              f"{share!r}")
        return cls(float(share))

    def describe(self) -> dict:
        share = getattr(self, self.share_key)
        return {self.share_key: share if share is not None else "read"}


def register_stage(cls):
    """Class decorator: add a ``Stage`` subclass to the registry and to ``STAGE_ORDER`` after ``cls.after``."""
    if not (isinstance(cls, type) and issubclass(cls, Stage)) or not cls.name:
        raise ConfigError(f"register_stage takes a Stage subclass with a name, got {cls!r}")
    if cls.name in _REGISTRY and _REGISTRY[cls.name] is not cls:
        raise ConfigError(f"a stage named {cls.name!r} is already registered ({_REGISTRY[cls.name].__module__})")
    if cls.after is not None and cls.after not in STAGE_ORDER:
        raise ConfigError(f"stage {cls.name!r} runs after {cls.after!r}, which is not registered (registered: "
                          f"{', '.join(STAGE_ORDER)})")
    _REGISTRY[cls.name] = cls
    if cls.name in STAGE_ORDER:
        STAGE_ORDER.remove(cls.name)
    STAGE_ORDER.insert(0 if cls.after is None else STAGE_ORDER.index(cls.after) + 1, cls.name)
    return cls


def unregister_stage(name: str) -> None:
    """Remove a registered stage (a test's toy stage, a plug-in being replaced); unknown names are refused."""
    if name not in _REGISTRY:
        raise ConfigError(f"no stage named {name!r} is registered (registered: {', '.join(STAGE_ORDER)})")
    del _REGISTRY[name]
    STAGE_ORDER.remove(name)


def registered_stages() -> dict:
    """{name: Stage class} of every registered stage, in run order."""
    return {n: _REGISTRY[n] for n in STAGE_ORDER}


def stage_metadata_keys() -> tuple:
    """The model metadata keys that switch registered stages on."""
    return tuple(c.metadata_key for c in registered_stages().values() if c.metadata_key)


MIN_FIT_POINTS = 16            # the fewest points an ``int`` cloud-points option may ask for


def int_option(name: str, value, low: int, high: int | None, meaning: str) -> int:
    """Check a stage's integer option (``meaning`` says what it counts for the error). Raises ``ConfigError``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low or \
            (high is not None and value > high):
        rng = f"{low}..{high}" if high is not None else f"≥ {low}"
        raise ConfigError(f"{name} must be 'auto' or an int in {rng} ({meaning}), got {value!r}")
    return int(value)


def enabled_option(stage: str, value, entry) -> bool:
    """A stage's ``enabled`` option: "auto" → whether the file holds the stage's metadata ``entry`` (not None), else
    the bool given. Raises ``ConfigError`` for anything else."""
    if isinstance(value, str) and value == "auto":
        return entry is not None
    if not isinstance(value, bool):
        raise ConfigError(f"{stage} enabled must be 'auto', True or False, got {value!r}")
    return value


def entry_options(options: dict, entry: dict) -> dict:
    """{key: ``options[key]``, or ``entry[key]`` where that option is "auto"} for every key of the stage's metadata
    ``entry`` (the file's values, or the stage's defaults where the file holds none)."""
    return {k: v if isinstance(options[k], str) and options[k] == "auto" else options[k] for k, v in entry.items()}


def cloud_points_option(stage: str, value) -> str | int:
    """Check a stage's ``points`` option over the crop: "cloud" (every point of the crop), "input" (the model input's
    N points) or an int n ≥ ``MIN_FIT_POINTS`` (the crop thinned by a regular stride to at most n points;
    ``ObjectState.cloud_points``). Raises ``ConfigError``."""
    if isinstance(value, str) and value in ("cloud", "input"):
        return value
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= MIN_FIT_POINTS:
        return int(value)
    raise ConfigError(f"{stage} points must be 'cloud', 'input' or an int ≥ {MIN_FIT_POINTS} (the crop thinned to at "
                      f"most that many points), got {value!r}")


@dataclass
class ObjectState:
    """One object on its way through the pipeline (model units, centred camera frame of its model input).

    Attributes:
        prep: its ``PreparedPoints`` (``model_points`` [N, 3], ``cloud`` [P, 3], ``centre_m``, ``scale``).
        R, t, scores: hypotheses [A, 3, 3], [A, 3], [A] (lower better); learned frame until ``calibrated``.
        canonical: [M, 3] predicted canonical shape, learned frame (the mean over rotated copies).
        template: the ICP template in the learned frame (``canonical`` unless a stage densifies it).
        copy_poses: rotated copies only: each copy's best (R [K, 3, 3], t [K, 3]) in the input's frame.
        consensus: rotated copies only: (R [3, 3], t [3], support [K] bool, ICP residual or None before re-scoring).
        rescored: the ICP re-scoring ran (scores are residuals); view_scored: the view-aware re-scoring ran.
        calibrated: R, t are in the category frame; canonical_category [M, 3] the shape there; learned: the
            hypotheses (R, t) before calibration; calibration: (δR [3, 3], δt [3]) applied.
        ambiguous_margin: flip margin below which the selection is ambiguous (None: the selection's default).
        selection: ``Selection`` of the chosen hypothesis; rotation [3, 3], translation [3] the pose (category
            frame → centred camera frame, model units).
        up: None or the unit camera-frame up the pose keeps; up_source "given" | "rest_facet" | None.
        support_up: None or the unit camera-frame normal of the support plane the object stands on, found in the
            depth frame whether or not an up prior was asked for (evidence only: no stage turns the pose to it);
            support_offset: its offset (m): a camera-frame point x lies ``support_up · x + support_offset`` above it.
        symmetry: the symmetry results report (a stage may settle it, e.g. the handle).
        ambiguous, confidence: the result's flags (stages may lower confidence or set ambiguous).
        prefer, prefer_margin: tracking's preferred hypothesis (index or rotation) and its margin; top_k: hypotheses
            listed in the result.
        extras: what stages add to the result (result field name → value).
        crop: the crop's diagnostics (``CropResult.diagnostics``; empty for point input).
    """
    prep: object
    R: np.ndarray
    t: np.ndarray
    scores: np.ndarray
    canonical: np.ndarray
    template: np.ndarray
    symmetry: str = "none"
    copy_poses: tuple | None = None
    consensus: tuple | None = None
    rescored: bool = False
    view_scored: bool = False
    calibrated: bool = False
    learned: tuple | None = None
    calibration: tuple | None = None
    canonical_category: np.ndarray | None = None
    ambiguous_margin: float | None = None
    selection: object = None
    rotation: np.ndarray | None = None
    translation: np.ndarray | None = None
    up: np.ndarray | None = None
    up_source: str | None = None
    support_up: np.ndarray | None = None
    support_offset: float | None = None
    ambiguous: bool = False
    confidence: float = 1.0
    prefer: object = None
    prefer_margin: float = 0.0
    top_k: int = 5
    extras: dict = field(default_factory=dict)
    crop: dict = field(default_factory=dict)
    _closure: tuple | None = field(default=None, repr=False)      # (rotation, translation, Closure) last read
    _normals: np.ndarray | None = field(default=None, repr=False)  # [N, 3] of the model input, once read

    @property
    def points(self) -> np.ndarray:
        """[N, 3] the model input points (model units, centred camera frame)."""
        return self.prep.model_points

    @property
    def every_point(self) -> np.ndarray:
        """[P, 3] every point FPS chose from (the whole crop, thinned), or the model input when that is all."""
        return self.prep.model_points if self.prep.cloud is None else self.prep.cloud

    def cloud_points(self, choice: str | int) -> np.ndarray:
        """[P', 3] the points a ``cloud_points_option`` names: "cloud" → ``every_point``, "input" → ``points``,
        n → ``every_point`` thinned by a regular stride to at most n points (deterministic; the crop's own order)."""
        if isinstance(choice, str):
            return self.every_point if choice == "cloud" else self.points
        cloud = self.every_point
        return cloud[:: -(-len(cloud) // choice)] if len(cloud) > choice else cloud

    def normals(self) -> np.ndarray:
        """[N, 3] unit normals of the model input points (``equipose.core.normals.point_normals``, ``NORMAL_NEIGHBOURS``
        neighbours each; sign arbitrary), computed once: stages that read them share them."""
        if self._normals is None:
            self._normals = point_normals(self.points, NORMAL_NEIGHBOURS)
        return self._normals

    def closure(self):
        """``equipose.core.opening.top_closure`` of the input points along the pose's category z through its centre
        (``cap``: the end the pose's +z points to; ``bottom``: the other), read once per pose: stages that read the
        same pose share it."""
        memo = self._closure
        if memo is not None and np.array_equal(memo[0], self.rotation) and np.array_equal(memo[1], self.translation):
            return memo[2]
        ends = top_closure(self.points, self.rotation[:, 2], self.translation)
        self._closure = (self.rotation.copy(), self.translation.copy(), ends)
        return ends

    def top_height(self) -> float:
        """Height (m) of the object's top above its support plane: ``TOP_PERCENTILE`` of its crop points' heights.
        Needs ``support_up``."""
        heights = self.prep.to_metres(self.every_point) @ self.support_up + self.support_offset    # [P] m
        return float(selected_percentile(np.ascontiguousarray(heights, np.float64), TOP_PERCENTILE))

    def at_height(self, translation, height_m: float) -> np.ndarray:
        """``translation`` [3] (model units) moved along the support plane's normal so that the centre lies
        ``height_m`` metres above the plane. Needs ``support_up``."""
        t = np.asarray(translation, np.float64)
        now = float(self.prep.to_metres(t) @ self.support_up + self.support_offset)                # m above the plane
        return t + (height_m - now) / self.prep.scale * np.asarray(self.support_up, np.float64)

    def set_pose(self, rotation, translation=None) -> None:
        """Replace the chosen pose (rotation [3, 3]; translation [3] model units, kept when None)."""
        self.rotation = np.asarray(rotation, np.float64).reshape(3, 3)
        if translation is not None:
            self.translation = np.asarray(translation, np.float64).reshape(3)
