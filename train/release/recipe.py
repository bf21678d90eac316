"""One release recipe per shipped model: ``train/release/recipes/<model>.toml``, read with ``tomllib``.

A recipe says how ``sdk/models/<model>{,.int8}.onnx`` is made from a training state: which network, which data, and
which stages go into the file's metadata. Every key, its type, its default and its meaning:

    state            str    training-state folder (``latest.pt`` + ``config.json``), relative to the repository root;
                            absent: keep the network of the shipped files and only re-calibrate and re-measure them
    category         str    the training category (data of the refined calibration, flip templates, frame priors)
    mode             str    "complete" | "partial": the network's input
    [export]
    category         str    the file's category and test set (default: ``category``), e.g. a cup network as "mug"
    scale            float  metres per model unit written into the file (default: the checkpoint's)
    [calibration]
    count            int    category-frame training inputs of both calibrations (default 512)
    [refine]                ICP re-scoring calibrated into the file (metadata ``refine_calibration``)
    k                int    hypotheses re-scored (default 5; 0: none, the file runs the plain network)
    iters            int    ICP iterations of the re-scoring (default 10)
    copies           int    rotated input copies per object (default 1)
    visibility       float  partial views: hidden-point-removal exponent of the view-aware re-scoring (default off)
    polish           int    ICP iterations on the selected pose (default 0)
    densify          int    ICP template plus midpoints to each point's N nearest neighbours (default 0)
    [flip]                  front/back templates (``equipose.export.flip_templates``); absent: none
    teacher          str    complete-shape model (shipped name or .onnx) that reconstructs the templates
    axes             str    comma-separated category axes whose half turns are checked (default "z")
    pool             int    reconstructions made; the 6 that agree on the frame are kept (default 24)
    [turn_classifier]       partial views (``equipose.train.fitting.turn_classifier``); absent: none
    state            str    train it on this lane's views posed by its teacher (the int8 file copies it), or
    copy_from        str    copy the classifier of this .onnx file instead
    axes             str    with ``state``: half-turn axes (default "x,y,z")
    student_frac     float  with ``state``: share of each batch posed by the model's own poses (default 0)
    student_max_deg  float  with ``state``: own poses farther than this from every teacher turn are left out (45)
    rest_facet       float  complete clouds: rest-facet stage tolerance, degrees (default off)
    frame_priors     str    complete clouds: "auto" | "none" | steps such as "footprint,mirror:x" (default off)
    [axis_centre]           partial bodies of revolution: the ``axis_centre`` stage, written before the centre and
                            confidence fits (which then see its centres); absent: the stage stays off
    points           str|int "input" | "cloud" | n points of the crop (default "input")
    max_shift        float  the largest move of the axis, per body radius, in (0, 2] (default 1)
    [rim_axis]              partial open containers (symmetry ``continuous:z``): the ``rim_axis`` stage, written
                            with ``[axis_centre]`` before the centre and confidence fits; absent: the stage stays off
    band             float  the top share of the extent along the axis that fits the rim plane, in (0, 1) (0.3)
    max_turn         float  the largest turn of the axis, degrees, in (0, 90] (default 30)
    points           str|int "input" | "cloud" | n points of the crop (default "cloud")
    [seat]                  partial containers and cans standing on a table: the ``seat`` stage's centre height
                            (``equipose.train.evaluation.seat``), fitted before the centre and confidence fits;
                            absent: the stage stays off
    views            int    rendered training views of the fit
    [confidence]            the calibrated confidence (``equipose.train.evaluation.confidence``)
    keep_weights     bool   keep the file's weights and choose only its ambiguity flags again (default false)
    views            int    tabletop models: rendered views of the fit (default 200)
    [eval]
    mode             str    the test set's input (default: ``mode``)
    icp_samples      int    test samples of the ICP-60 baseline in the same evaluation (default 100)

Unknown keys and bad values raise ``ConfigError`` naming the file and the key.
"""
from __future__ import annotations

import dataclasses
import pathlib

from equipose.core.errors import ConfigError
from equipose.core.metadata import FRAME_PRIOR_STEPS, MAX_COPIES, MAX_DENSIFY, MAX_POLISH
from equipose.runtime.stage import MIN_FIT_POINTS, cloud_points_option
from equipose.runtime.stages.axis_centre import parse_axis_centre
from equipose.runtime.stages.rim_axis import parse_rim_axis

__all__ = ["Recipe", "RECIPES_DIR", "REPO", "load_recipe", "recipe_path", "shipped_models"]

REPO = pathlib.Path(__file__).resolve().parents[2]
RECIPES_DIR = pathlib.Path(__file__).resolve().parent / "recipes"
MODELS_DIR = REPO / "sdk" / "models"
AXES = ("x", "y", "z")


@dataclasses.dataclass(frozen=True)
class Recipe:
    """A validated recipe (field names: ``<table>_<key>`` for keys of a table)."""
    name: str
    source: str
    category: str
    mode: str
    state: str | None = None
    export_category: str = ""
    export_scale: float | None = None
    calibration_count: int = 512
    refine_k: int = 5
    refine_iters: int = 10
    refine_copies: int = 1
    refine_visibility: float | None = None
    refine_polish: int = 0
    refine_densify: int = 0
    flip_teacher: str | None = None
    flip_axes: str = "z"
    flip_pool: int = 24
    turn_state: str | None = None
    turn_copy_from: str | None = None
    turn_axes: str = "x,y,z"
    turn_student_frac: float = 0.0
    turn_student_max_deg: float = 45.0
    rest_facet: float | None = None
    frame_priors: str | None = None
    eval_mode: str = ""
    eval_icp_samples: int = 100
    centre_views: int | None = None
    confidence_keep_weights: bool = False
    confidence_views: int | None = None
    rest_side_views: int | None = None
    rest_side_upright_views: int | None = None
    rest_side_upright_height_views: int | None = None
    flip_risk_views: int | None = None
    flip_risk_shapes: int | None = None
    flip_risk_flag_share: float = 0.3
    axis_centre_points: str | int | None = None
    axis_centre_max_shift: float | None = None
    rim_axis_band: float | None = None
    rim_axis_max_turn: float | None = None
    rim_axis_points: str | int | None = None
    seat_views: int | None = None

    @property
    def axis_centre(self) -> dict | None:
        """The ``axis_centre`` metadata entry the recipe writes (the stage's defaults for keys it leaves out), or
        None."""
        given = {k: v for k, v in (("points", self.axis_centre_points), ("max_shift", self.axis_centre_max_shift))
                 if v is not None}
        return parse_axis_centre(given, self.source) if given else None

    @property
    def rim_axis(self) -> dict | None:
        """The ``rim_axis`` metadata entry the recipe writes (the stage's defaults for keys it leaves out), or None."""
        given = {k: v for k, v in (("band", self.rim_axis_band), ("max_turn", self.rim_axis_max_turn),
                                   ("points", self.rim_axis_points)) if v is not None}
        return parse_rim_axis(given, self.source) if given else None


def _text(v):
    return isinstance(v, str) and bool(v.strip())


def _int(lo, hi=None):
    return lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= lo and (hi is None or v <= hi)


def _float(lo, hi=None, open_lo=False, closed_hi=False):
    def ok(v):
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            return False
        return (v > lo if open_lo else v >= lo) and (hi is None or (v <= hi if closed_hi else v < hi))
    return ok


def _points(v):
    try:
        cloud_points_option("axis_centre", v)
    except ConfigError:
        return False
    return True


def _axes(v):
    parts = [p.strip() for p in v.split(",")] if isinstance(v, str) else []
    return bool(parts) and all(p in AXES for p in parts) and len(set(parts)) == len(parts)


def _mode(v):
    return v in ("complete", "partial")


def _frame_priors(v):
    if v in ("auto", "none"):
        return True
    if not isinstance(v, str):
        return False
    for part in v.split(","):
        name, _, axis = part.strip().partition(":")
        if name not in FRAME_PRIOR_STEPS or (name == "mirror") != bool(axis) or (axis and axis not in AXES):
            return False
    return True


# (table, key) → (field, check, what a valid value is); table "" = top level
SCHEMA = {
    ("", "state"): ("state", _text, "a folder path"),
    ("", "category"): ("category", _text, "a category name"),
    ("", "mode"): ("mode", _mode, '"complete" or "partial"'),
    ("", "rest_facet"): ("rest_facet", _float(0, 90, open_lo=True), "degrees in (0, 90)"),
    ("", "frame_priors"): ("frame_priors", _frame_priors, '"auto", "none" or steps like "footprint,mirror:x"'),
    ("export", "category"): ("export_category", _text, "a category name"),
    ("export", "scale"): ("export_scale", _float(0, open_lo=True), "metres per model unit > 0"),
    ("calibration", "count"): ("calibration_count", _int(1), "an integer ≥ 1"),
    ("refine", "k"): ("refine_k", _int(0, 60), "an integer in 0–60"),
    ("refine", "iters"): ("refine_iters", _int(1), "an integer ≥ 1"),
    ("refine", "copies"): ("refine_copies", _int(1, MAX_COPIES), f"an integer in 1–{MAX_COPIES}"),
    ("refine", "visibility"): ("refine_visibility", _float(0, open_lo=True), "an exponent > 0"),
    ("refine", "polish"): ("refine_polish", _int(0, MAX_POLISH), f"an integer in 0–{MAX_POLISH}"),
    ("refine", "densify"): ("refine_densify", _int(0, MAX_DENSIFY), f"an integer in 0–{MAX_DENSIFY}"),
    ("flip", "teacher"): ("flip_teacher", _text, "a shipped model name or .onnx path"),
    ("flip", "axes"): ("flip_axes", _axes, 'comma-separated axes among x, y, z, e.g. "z"'),
    ("flip", "pool"): ("flip_pool", _int(6), "an integer ≥ 6 (6 templates are kept)"),
    ("turn_classifier", "state"): ("turn_state", _text, "a folder path"),
    ("turn_classifier", "copy_from"): ("turn_copy_from", _text, "an .onnx path"),
    ("turn_classifier", "axes"): ("turn_axes", _axes, 'comma-separated axes among x, y, z, e.g. "x,y,z"'),
    ("turn_classifier", "student_frac"): ("turn_student_frac", _float(0, 1), "a share in [0, 1)"),
    ("turn_classifier", "student_max_deg"): ("turn_student_max_deg", _float(0, 180, open_lo=True), "degrees"),
    ("eval", "mode"): ("eval_mode", _mode, '"complete" or "partial"'),
    ("eval", "icp_samples"): ("eval_icp_samples", _int(1), "an integer ≥ 1"),
    ("centre", "views"): ("centre_views", _int(1), "rendered training views, an integer ≥ 1"),
    ("confidence", "keep_weights"): ("confidence_keep_weights", lambda v: isinstance(v, bool), "true or false"),
    ("confidence", "views"): ("confidence_views", _int(1), "rendered tabletop views, an integer ≥ 1"),
    ("rest_side", "views"): ("rest_side_views", _int(1), "rendered views, an integer ≥ 1"),
    ("rest_side", "upright_views"): ("rest_side_upright_views", _int(1), "rendered views, an integer ≥ 1"),
    ("rest_side", "upright_height_views"): ("rest_side_upright_height_views", _int(1),
                                            "rendered training views, an integer ≥ 1"),
    ("flip_risk", "views"): ("flip_risk_views", _int(1), "rendered views per training shape, an integer ≥ 1"),
    ("flip_risk", "shapes"): ("flip_risk_shapes", _int(1), "the first N training shapes, an integer ≥ 1"),
    ("flip_risk", "flag_share"): ("flip_risk_flag_share", _float(0, 1, open_lo=True), "a share in (0, 1)"),
    ("axis_centre", "points"): ("axis_centre_points", _points, f'"input", "cloud" or an integer ≥ {MIN_FIT_POINTS}'),
    ("axis_centre", "max_shift"): ("axis_centre_max_shift", _float(0, 2, open_lo=True, closed_hi=True),
                                   "a share of the body radius in (0, 2]"),
    ("rim_axis", "band"): ("rim_axis_band", _float(0, 1, open_lo=True), "a share in (0, 1)"),
    ("rim_axis", "max_turn"): ("rim_axis_max_turn", _float(0, 90, open_lo=True, closed_hi=True),
                               "degrees in (0, 90]"),
    ("rim_axis", "points"): ("rim_axis_points", _points, f'"input", "cloud" or an integer ≥ {MIN_FIT_POINTS}'),
    ("seat", "views"): ("seat_views", _int(1), "rendered training views, an integer ≥ 1"),
}
TABLES = sorted({t for t, _ in SCHEMA if t})


def recipe_path(name: str) -> pathlib.Path:
    return RECIPES_DIR / f"{name}.toml"


def shipped_models(models_dir=MODELS_DIR) -> list:
    """Names of the shipped fp32 files (``sdk/models/<name>.onnx``; the ``.int8`` copies follow them)."""
    return sorted(p.name[:-len(".onnx")] for p in pathlib.Path(models_dir).glob("*.onnx") if ".int8." not in p.name)


def _flatten(data: dict, source: str) -> dict:
    """TOML tables → {(table, key): value}; unknown tables and keys raise ``ConfigError``."""
    flat = {}
    for key, value in data.items():
        if isinstance(value, dict):
            if key not in TABLES:
                raise ConfigError(f"{source}: unknown table [{key}]; known tables: {', '.join(TABLES)}")
            if not value:
                raise ConfigError(f"{source}: table [{key}] is empty; give its keys or leave the table out")
            items = [((key, k), v) for k, v in value.items()]
        else:
            items = [(("", key), value)]
        for (table, k), v in items:
            if (table, k) not in SCHEMA:
                known = sorted(kk for t, kk in SCHEMA if t == table and kk not in TABLES)
                where = f"[{table}] " if table else ""
                raise ConfigError(f"{source}: unknown key {where}{k!r}; known: {', '.join(known)}")
            flat[(table, k)] = v
    return flat


def _check_combinations(r: Recipe, source: str) -> None:
    partial_only = {"[refine] visibility": r.refine_visibility is not None,
                    "[turn_classifier]": bool(r.turn_state or r.turn_copy_from),
                    "[centre]": r.centre_views is not None, "[flip_risk]": r.flip_risk_views is not None,
                    "[axis_centre]": r.axis_centre is not None, "[rim_axis]": r.rim_axis is not None,
                    "[seat]": r.seat_views is not None,
                    "[rest_side]": r.rest_side_views is not None or r.rest_side_upright_views is not None
                    or r.rest_side_upright_height_views is not None}
    complete_only = {"rest_facet": r.rest_facet is not None, "frame_priors": r.frame_priors is not None}
    for what, used in partial_only.items():
        if used and r.mode != "partial":
            raise ConfigError(f"{source}: {what} applies to partial-view models; this recipe has mode {r.mode!r}")
    for what, used in complete_only.items():
        if used and r.mode != "complete":
            raise ConfigError(f"{source}: {what} applies to complete-shape models; this recipe has mode {r.mode!r}")
    if bool(r.turn_state) == bool(r.turn_copy_from) and (r.turn_state or r.turn_copy_from):
        raise ConfigError(f"{source}: [turn_classifier] takes either state or copy_from, not both")
    if r.turn_copy_from and (r.turn_student_frac or r.turn_axes != "x,y,z" or r.turn_student_max_deg != 45.0):
        raise ConfigError(f"{source}: [turn_classifier] axes / student_frac / student_max_deg go with state "
                          "(copy_from copies a trained classifier as it is)")


def load_recipe(path, name: str | None = None) -> Recipe:
    """Read and validate one recipe; ``name`` (default: the file name) is the model it ships."""
    try:
        import tomllib
    except ModuleNotFoundError:                                    # Python 3.10
        try:
            import tomli as tomllib
        except ModuleNotFoundError:
            raise ConfigError("reading a release recipe needs Python ≥ 3.11 (tomllib) or the tomli package") from None
    path = pathlib.Path(path)
    source = str(path)
    if not path.is_file():
        raise ConfigError(f"no recipe at {source} (one per shipped model in {RECIPES_DIR})")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{source}: not valid TOML: {e}") from None
    values = {"name": name or path.stem, "source": source}
    for (table, key), value in _flatten(data, source).items():
        field, ok, expected = SCHEMA[(table, key)]
        if not ok(value):
            where = f"[{table}] {key}" if table else key
            raise ConfigError(f"{source}: {where} must be {expected}, got {value!r}")
        values[field] = float(value) if isinstance(value, int) and field in _FLOAT_FIELDS else value
    for required in ("category", "mode"):
        if required not in values:
            raise ConfigError(f"{source}: {required!r} is required")
    recipe = Recipe(**values)
    recipe = dataclasses.replace(recipe, export_category=recipe.export_category or recipe.category,
                                 eval_mode=recipe.eval_mode or recipe.mode)
    _check_combinations(recipe, source)
    return recipe


_FLOAT_FIELDS = {f.name for f in dataclasses.fields(Recipe) if "float" in str(f.type)}
