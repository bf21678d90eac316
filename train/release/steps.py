"""The release steps of one recipe, and the command that runs them (``python -m equipose.train.release MODEL``).

From a training state: calibrate the checkpoint → export fp32 + int8 → per file: refined calibration for the SDK's
ICP re-scoring and the plain network's evaluation → rest facet, flip templates, turn classifier, frame priors (as the
recipe asks) → evaluation through the SDK (ICP-60 in the same command), stored in the file's ``metrics`` metadata.
Without a state the shipped files keep their network and are re-calibrated and re-measured.

Writes ``sdk/models/MODEL{,.int8}.onnx`` and ``docs/results/models/MODEL{,.int8}{.json,.png,.txt,.norefine.txt}``;
``STATE/calibrated.pt`` and ``STATE/calibrate.log`` beside the checkpoint. Paths are relative to the repository root,
where every step runs.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import shlex
import subprocess
import sys

from equipose.core.errors import ConfigError
from equipose.train.release.recipe import REPO, Recipe, load_recipe, recipe_path

__all__ = ["Step", "plan", "run_steps", "main"]

MODELS = "sdk/models"
RESULTS = "docs/results/models"


@dataclasses.dataclass(frozen=True)
class Step:
    """One step: a command line (``argv[0]`` "equipose" = the CLI, "python" = this interpreter) or, with ``call``, a
    Python function; ``tee``: stdout is also written to this file."""
    title: str
    argv: tuple = ()
    tee: str | None = None
    call: object = None

    def text(self) -> str:
        line = self.argv[0] if self.call is not None else shlex.join(self.argv)
        return line + (f" | tee {self.tee}" if self.tee else "")


CONFIDENCE_VIEWS = 200          # rendered tabletop views for the confidence fit (ModelNet models use their test set)


def _equipose(*args, title, tee=None) -> Step:
    return Step(title, ("equipose",) + tuple(str(a) for a in args), tee)


def _python(module, *args, title) -> Step:
    return Step(title, ("python", "-m", module) + tuple(str(a) for a in args))


def _views(state: str | None) -> int:
    """Rendered views per training instance of the state's cache (its config.json; 10 without a state)."""
    if state is None:
        return 10
    cfg = REPO / state / "config.json"
    missing = [f for f in ("latest.pt", "config.json") if not (REPO / state / f).is_file()]
    if missing:
        raise ConfigError(f"training state {state}: no {' or '.join(missing)} there (a state folder holds the "
                          "checkpoint latest.pt and its config.json)")
    return int(json.loads(cfg.read_text()).get("views", 10))


def _set_metadata(path: str, **entries) -> None:
    from equipose.export.onnx_export import update_metadata
    update_metadata(REPO / path, **entries)


def _metadata_step(title: str, model: str, key: str, value) -> Step:
    """A step that writes one metadata entry ``key`` = ``value`` into ``model``."""
    return Step(title, (f"update_metadata({model}, {key}={value})",), call=lambda: _set_metadata(model, **{key: value}))


def _file_steps(r: Recipe, f: str, views: int, skip_eval: bool) -> list:
    """The steps of one file (``f``: "MODEL" or "MODEL.int8")."""
    model, steps = f"{MODELS}/{f}.onnx", []
    test = ("--category", r.export_category, "--mode", r.eval_mode)
    if r.refine_k:
        extra = [] if r.refine_visibility is None else ["--visibility", r.refine_visibility]
        steps.append(_equipose("calibrate", "--model", model, "--num", r.calibration_count, "--views", views,
                               "--refine", r.refine_k, "--refine-iters", r.refine_iters, "--copies", r.refine_copies,
                               *extra, "--polish", r.refine_polish, "--densify", r.refine_densify,
                               title=f"{f}: refined calibration for the ICP re-scoring of {r.refine_k} hypotheses"))
        if not skip_eval:
            steps.append(_equipose("eval", "--model", model, *test, "--refine", 0, "--icp-templates", 0,
                                   title=f"{f}: the plain network, for reference", tee=f"{RESULTS}/{f}.norefine.txt"))
    if r.rest_facet is not None:
        steps.append(_metadata_step(f"{f}: rest facet, {r.rest_facet:g}° tolerance", model, "rest_facet",
                                    {"tolerance_deg": float(r.rest_facet)}))
    if r.flip_teacher:
        steps.append(_python("equipose.export.flip_templates", "--model", model, "--teacher", r.flip_teacher,
                             "--category", r.category, "--axes", r.flip_axes, "--pool", r.flip_pool,
                             title=f"{f}: front/back templates from {r.flip_teacher}"))
    turn = "equipose.train.fitting.turn_classifier"
    if r.turn_copy_from:
        steps.append(_python(turn, "--model", model, "--copy-from", r.turn_copy_from,
                             title=f"{f}: turn classifier copied from {r.turn_copy_from}"))
    elif r.turn_state and f == r.name:
        frac = [] if not r.turn_student_frac else ["--student-frac", r.turn_student_frac,
                                                   "--student-max-deg", r.turn_student_max_deg]
        steps.append(_python(turn, "--model", model, "--state", r.turn_state, "--axes", r.turn_axes, *frac,
                             title=f"{f}: turn classifier trained on {r.turn_state}"))
    elif r.turn_state:
        steps.append(_python(turn, "--model", model, "--copy-from", f"{MODELS}/{r.name}.onnx",
                             title=f"{f}: the fp32 file's turn classifier"))
    if r.frame_priors is not None:
        steps.append(_python("equipose.export.frame_priors", "--model", model, "--category", r.category,
                             "--steps", r.frame_priors, title=f"{f}: frame priors ({r.frame_priors})"))
    if r.rim_axis is not None:                      # before the centre and confidence fits: they see its axes
        steps.append(_metadata_step(f"{f}: the rim_axis stage ({r.rim_axis})", model, "rim_axis", r.rim_axis))
    if r.axis_centre is not None:                   # before the centre and confidence fits: they see its centres
        steps.append(_metadata_step(f"{f}: the axis_centre stage ({r.axis_centre})", model, "axis_centre",
                                    r.axis_centre))
    if r.seat_views and f == r.name:                # before the centre and confidence fits: they see its centres
        steps.append(_python("equipose.train.evaluation.seat", "--model", model, "--views", r.seat_views, "--write",
                             title=f"{f} (and its int8 copy): the seat stage's centre height"))
    if r.flip_risk_views and f == r.name:           # before the confidence fit: its flag is what the confidence reads
        shapes = [] if r.flip_risk_shapes is None else ["--shapes", r.flip_risk_shapes]
        steps.append(_python("equipose.train.evaluation.flip_risk", "--model", model, "--views", r.flip_risk_views,
                             *shapes, "--flag-share", r.flip_risk_flag_share, "--write",
                             title=f"{f} (and its int8 copy): the chance of a half turn, and its flag"))
    if r.centre_views and f == r.name:              # before the confidence fit: the offset decides which are right
        steps.append(_python("equipose.train.evaluation.centre", "--model", model, "--views", r.centre_views,
                             "--write", title=f"{f} (and its int8 copy): the centre's depth offset"))
    if r.rest_side_views and f == r.name:           # before the confidence fit: the turned poses are what it sees
        steps.append(_python("equipose.train.evaluation.rest_side", "--model", model, "--views", r.rest_side_views,
                             "--write", title=f"{f} (and its int8 copy): when the up prior stands it on its opening"))
    if r.rest_side_upright_views and f == r.name:   # likewise: the poses stood upright are what the confidence sees
        steps.append(_python("equipose.train.evaluation.rest_side", "--upright", "--model", model, "--views",
                             r.rest_side_upright_views, "--write",
                             title=f"{f} (and its int8 copy): when a pose on its opening is stood upright"))
    if r.rest_side_upright_height_views and f == r.name:   # the centre of the poses stood upright (training shapes)
        steps.append(_python("equipose.train.evaluation.rest_side", "--upright", "--height", "--model", model,
                             "--views", r.rest_side_upright_height_views, "--write",
                             title=f"{f} (and its int8 copy): the centre height of a pose stood upright"))
    if f == r.name:                                                            # also written into the int8 file
        keep = ["--flags-only"] if r.confidence_keep_weights else []
        views = CONFIDENCE_VIEWS if r.confidence_views is None else r.confidence_views
        steps.append(_python("equipose.train.evaluation.confidence", "--model", model, "--views", views,
                             "--write", *keep, title=f"{f} (and its int8 copy): calibrated confidence"
                             + (" (its weights kept, its flags chosen again)" if keep else "")))
    if not skip_eval:
        steps.append(_equipose("eval", "--model", model, *test, "--icp-samples", r.eval_icp_samples,
                               "--json", f"{RESULTS}/{f}.json", "--plot", f"{RESULTS}/{f}.png", "--store-metrics",
                               title=f"{f}: evaluation through the SDK, metrics stored in the file",
                               tee=f"{RESULTS}/{f}.txt"))
    return steps


def plan(recipe: Recipe, *, state: str | None = None, skip_eval: bool = False) -> list:
    """Every step of ``recipe`` in order. ``state``: a folder instead of the recipe's ("-": keep the shipped
    network); ``skip_eval``: leave out both evaluations (the files' ``metrics`` metadata is then not refreshed)."""
    state = recipe.state if state is None else (None if state == "-" else str(state))
    views = _views(state)
    steps = []
    if state is not None:
        scale = [] if recipe.export_scale is None else ["--scale", recipe.export_scale]
        steps.append(_equipose("calibrate", "--checkpoint", f"{state}/latest.pt", "--num", recipe.calibration_count,
                               "--out", f"{state}/calibrated.pt", title="calibrate the checkpoint's frame",
                               tee=f"{state}/calibrate.log"))
        steps.append(_equipose("export", "--checkpoint", f"{state}/calibrated.pt", "-o",
                               f"{MODELS}/{recipe.name}.onnx", "--int8", "--category", recipe.export_category,
                               *scale, title="export fp32 + int8"))
    for f in (recipe.name, f"{recipe.name}.int8"):
        steps += _file_steps(recipe, f, views, skip_eval)
    return steps


def _command(argv: tuple) -> list:
    if argv[0] == "equipose":
        return [sys.executable, "-m", "equipose.cli", *argv[1:]]
    if argv[0] == "python":
        return [sys.executable, *argv[1:]]
    return list(argv)


def run_steps(steps: list, *, dry_run: bool = False, out=print) -> None:
    """Print each step and (unless ``dry_run``) run it in the repository root; a failing step stops the release."""
    for i, step in enumerate(steps, 1):
        out(f"[{i}/{len(steps)}] {step.title}\n    {step.text()}")
        if dry_run:
            continue
        if step.call is not None:
            step.call()
            continue
        with subprocess.Popen(_command(step.argv), cwd=REPO, stdout=subprocess.PIPE, text=True, bufsize=1) as proc:
            tee = open(REPO / step.tee, "w") if step.tee else None
            try:
                for line in proc.stdout:
                    sys.stdout.write(line)
                    if tee:
                        tee.write(line)
            finally:
                if tee:
                    tee.close()
        if proc.returncode:
            raise SystemExit(f"step {i} ({step.title}) failed with exit status {proc.returncode}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m equipose.train.release",
                                 description="Ship a model from its recipe (train/release/recipes/MODEL.toml): "
                                             "calibrate, export fp32 + int8, add its stages, evaluate.")
    ap.add_argument("model", help="the shipped model to make (sdk/models/MODEL.onnx)")
    ap.add_argument("--recipe", help="recipe file (default: train/release/recipes/MODEL.toml)")
    ap.add_argument("--state", help="training-state folder instead of the recipe's (e.g. a weight average); "
                                    "'-' keeps the shipped network (re-calibrate and re-measure)")
    ap.add_argument("--dry-run", action="store_true", help="print the steps without running them")
    ap.add_argument("--skip-eval", action="store_true",
                    help="leave out the evaluations (the files' stored metrics are then not refreshed)")
    a = ap.parse_args(argv)
    try:
        recipe = load_recipe(a.recipe or recipe_path(a.model), name=a.model)
        steps = plan(recipe, state=a.state, skip_eval=a.skip_eval)
    except ConfigError as e:
        print(f"release {a.model}: error: {e}", file=sys.stderr)
        return 2
    source = pathlib.Path(recipe.source).resolve()
    shown = source.relative_to(REPO) if source.is_relative_to(REPO) else source
    print(f"release {recipe.name} from {shown}" + (" (dry run)" if a.dry_run else ""))
    run_steps(steps, dry_run=a.dry_run)
    return 0
