"""Confidence calibration: the result's evidence → the chance that its pose is right, fitted per model file on rendered
tabletop views with occluders and sensor noise (``equipose.train.data.occluded``).

    python -m equipose.train.evaluation.confidence --model sdk/models/mug-tabletop.onnx [--views 240] [--seed 0]
        [--write] [--json F] [--plot F] [--data-root DIR] [--rows F] [--without F1,F2] [--flags-only] [--check]
        [--standing-only]

Each view runs through ``PoseEstimator.predict`` four times: box prompt (the visible mask's bounding box, as a
detector gives it) and mask prompt, each without and with the up prior "plane". A pose is *right* when its rotation
is within 10° of the truth modulo the model's symmetry (mugs: full 6D; cans: unsigned axis) and its centre within
2 cm. The logistic model σ(bias + Σ wᵢ·featureᵢ) over ``equipose.runtime.stages.confidence``'s evidence is fitted on
the views of even-numbered test shapes (its features chosen there by shape-grouped cross-validation: the selection
margin alone, both margins, or all) and measured on the odd-numbered ones (shape-disjoint); ``--write`` stores
the fitted model (and its held-out figures) as ``confidence_calibration`` in the model file and its int8 sibling.
``--flags-only`` keeps the file's weights and chooses only its ambiguity flags again (``runner_up_margin``,
``closed_top_cap``); ``--check`` scores the stored confidence on the views instead of fitting.
ModelNet models (car, chair, ...) are fitted on their paper test set instead (``collect_modelnet``).

Convention: angles in degrees, distances in metres, probabilities in [0, 1]; AUROC for "right" (1 = right ranked
above every wrong), ECE over 10 equal-width bins, "confident-wrong" = error > 30°, confidence > 0.5, not ambiguous.
"""
from __future__ import annotations

import json
import pathlib
import sys
import time

import numpy as np
from scipy.optimize import minimize

from equipose.core.errors import ConfigError, EquiposeError
from equipose.core.logistic import logistic
from equipose.core.metadata import CONFIDENCE_FEATURES
from equipose.eval.metrics import auroc
from equipose.runtime.stages.confidence import (TURNED, below_runner_up, closed_top, open_bottom_up,
                                                turned_closed_top)
from equipose.runtime.stages.rest_side import HALF_TURN_X
from equipose.train.evaluation.fit_cli import fit_parser

__all__ = ["RIGHT_DEG", "RIGHT_M", "RIGHT_DIAG", "LYING_EVERY", "UPSIDE_DOWN_EVERY", "PROMPTS", "collect", "view_rest",
           "view_results", "handle_parts", "occluded_views", "collect_modelnet", "fit_logistic", "auroc", "reliability",
           "summarize", "runner_up_margin", "closed_top_cap", "choose_flags", "flag_rows", "grouped_log_loss",
           "feature_matrix", "main"]

RIGHT_DEG = 10.0        # a right pose: rotation error ≤ this (modulo symmetry) ...
RIGHT_M = 0.02          # ... and centre error ≤ this (metres)
RIGHT_DIAG = 0.05       # ModelNet models: centre error ≤ this share of the bounding-box diagonal instead
LYING_EVERY = 3         # cylinders: every third calibration view lies on its side
UPSIDE_DOWN_EVERY = 8   # open containers (cups, mugs, bowls): every eighth stands on its opening
PROMPTS = ("box", "mask")    # the calibration views' prompts: a detector's box, the visible mask
WRONG_DEG = 30.0        # confident-wrong: error above this with confidence > 0.5, not flagged ambiguous
L2 = 1e-3               # ridge on the standardised weights (per mean log-loss)


def _truth_symmetry(est) -> tuple:
    """(symmetry string, unsigned axis) the ground truth is compared under: mugs are full 6D (their handle stage),
    cylinders ("shape_prior": cylinder) have no axis sign."""
    if est.metadata.get("handle") is not None:
        return "none", False
    return est.symmetry, est.metadata.get("shape_prior") == "cylinder"


def collect(model, views: int, seed: int = 0, data_root=None, progress: bool = True,
            upside_down: bool | None = None) -> list:
    """Rows of one model on ``views`` rendered occluded views × {box, mask} × {no up, up "plane"}.

    Convention: each row {"shape", "view", "prompt", "up", "rot_err" (deg), "axis_err" (deg, the up axis),
    "centre_err" (m), "right" (bool),
    "confidence", "ambiguous", "occluded" (true hidden share), "ms", **evidence} (+ mugs: "handle_truth_px" the
    handle's visible pixels in the render, "handle_visible", "handle_points" the result's); views cycle through the
    test shapes of the model's tabletop category. Cylinders (``shape_prior`` "cylinder": cans) also rest on their
    side: every ``LYING_EVERY``-th view lies (``"rest"``: "lying", else "standing"), since a fallen can is as
    common on a table as a standing one; open containers (``TabletopSpec.upside_down``: cups, mugs, bowls) stand on
    their opening in every ``UPSIDE_DOWN_EVERY``-th view (``"rest"``: "upside_down"), as they are put away
    (``upside_down``: None = as the category's ``TabletopSpec`` says, False = never, as up to 0.40)."""
    from equipose import PoseEstimator
    from equipose.eval.metrics import rotation_errors
    from equipose.train.data.tabletop import TABLETOP, tabletop_sources
    from equipose.train.data.modelnet import default_data_root

    est = PoseEstimator(model) if not hasattr(model, "predict") else model
    if est.category not in TABLETOP:
        raise ConfigError(f"confidence calibration renders tabletop scenes; {est.category!r} is not one of "
                          f"{', '.join(TABLETOP)}")
    sources = tabletop_sources(data_root or default_data_root(), est.category, "test")
    symmetry, unsigned = _truth_symmetry(est)
    handle = est.metadata.get("handle")
    parts = handle_parts(est, sources)
    rows = []
    for v, s, view, rest in occluded_views(sources, views, seed, est.metadata.get("shape_prior") == "cylinder", parts,
                                           desc=f"confidence {est.category}", progress=progress,
                                           upside_down=TABLETOP[est.category].upside_down if upside_down is None
                                           else upside_down):
        for prompt, up, r, ms in view_results(est, view, ups=(None, "plane")):
            rot = float(rotation_errors(r.rotation[None], view.R[None], symmetry, unsigned_axis=unsigned)[0])
            centre = float(np.linalg.norm(r.translation - view.t))
            axis = float(rotation_errors(r.rotation[None], view.R[None], "continuous:z", unsigned_axis=unsigned)[0])
            rows.append({"shape": s, "view": v, "prompt": prompt, "up": up or "none",
                         "rest": rest, "rot_err": rot, "axis_err": axis,
                         "centre_err": centre, "right": bool(rot <= RIGHT_DEG and centre <= RIGHT_M),
                         "confidence": float(r.confidence), "ambiguous": bool(r.ambiguous),
                         "occluded": float(view.occluded), "ms": ms, **r.extras["evidence"]})
            if handle is not None:
                rows[-1].update(handle_truth_px=view.part_pixels, handle_visible=bool(r.handle_visible),
                                handle_points=int(r.handle_points))
    return rows


def handle_parts(est, sources: list) -> list | None:
    """[each source's handle-zone points (bool over its points)] for a model with a ``handle`` (mugs), else None: the
    part whose visible pixels the renders count (``OccludedView.part_pixels``)."""
    handle = est.metadata.get("handle")
    if handle is None:
        return None
    from equipose.core.handles import handle_zone_mask
    return [handle_zone_mask(src[1]["points"], src[1]["points"], handle) for src in sources]


def view_rest(v: int, count: int, lying: bool, upside_down: bool) -> str:
    """How the ``v``-th calibration view over ``count`` sources rests: "lying" (cylinders, ``lying``: every
    ``LYING_EVERY``-th view), "upside_down" (open containers, ``upside_down``: every ``UPSIDE_DOWN_EVERY``-th, the
    phase moved on by one in each round through the sources, so that even- and odd-numbered shapes, the fit's and the
    held-out half, both stand on their opening) or "standing"."""
    if lying and v % LYING_EVERY == LYING_EVERY - 1:
        return "lying"
    if upside_down and (v % count + v // count) % UPSIDE_DOWN_EVERY == UPSIDE_DOWN_EVERY - 1:
        return "upside_down"
    return "standing"


def occluded_views(sources: list, views: int, seed: int, lying: bool, parts: list | None = None, desc: str = "",
                   progress: bool = True, upside_down: bool = False):
    """Yield (view index v, source index s, ``OccludedView``, its rest: "standing" | "lying" | "upside_down") for v in
    0..``views``−1: source v mod len(sources) (``tabletop_sources`` entries; ``parts`` [its part points or None] per
    source) rendered behind an occluder with the generator seeded [``seed``, v]; with ``lying`` (cylinders) every
    ``LYING_EVERY``-th view lies on its side, with ``upside_down`` (open containers) some stand on their opening
    (``view_rest``). Views that ``render_occluded`` cannot make are skipped."""
    from tqdm import tqdm

    from equipose.train.data.occluded import render_occluded
    turns = {"lying": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),   # 90° about x: axis level
             "upside_down": HALF_TURN_X}                                                # 180° about x
    parts = [None] * len(sources) if parts is None else parts
    for v in tqdm(range(views), desc=desc, disable=not progress):
        s = v % len(sources)
        rest = view_rest(v, len(sources), lying, upside_down)
        view = render_occluded(sources[s][1], np.random.default_rng([seed, v]), part=parts[s], rest=turns.get(rest))
        if view is not None:
            yield v, s, view, rest


def view_results(est, view, ups=(None,)):
    """Yield (prompt, up, ``PoseResult``, ms) for a rendered ``view`` (``OccludedView``) under each of ``ups``, with
    the box prompt (the visible mask's bounding box, as a detector gives it) and the mask prompt, in that order; a
    prediction the SDK refuses (``EquiposeError``) is left out. ms: the wall time of ``est.predict``."""
    for prompt in PROMPTS:
        region = {"box": view.box} if prompt == "box" else {"mask": view.mask}
        for up in ups:
            t0 = time.perf_counter()
            try:
                r = est.predict(view.depth, view.K, depth_unit="mm", up=up, **region)
            except EquiposeError:
                continue
            yield prompt, up, r, (time.perf_counter() - t0) * 1e3


def collect_modelnet(model, data_root=None, cache_dir=None, limit: int | None = None, progress: bool = True) -> list:
    """Rows of a ModelNet model (not tabletop) on its paper test set: partial models on the rendered test views,
    complete models on the seeded rotations of the complete test clouds, through ``predict_points``.

    Convention: rows as ``collect``'s ("prompt" = "points", "up" = "none", "shape" = the test instance); ModelNet
    shapes have no metric size, so *right* = rotation within 10° (the evaluation's symmetry) and centre within
    ``RIGHT_DIAG`` of the instance's bounding-box diagonal (the paper's translation unit)."""
    from tqdm import tqdm

    from equipose import PoseEstimator
    from equipose.eval.metrics import rotation_errors
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.evaluation.evaluate import test_dataset

    est = PoseEstimator(model) if not hasattr(model, "predict") else model
    mode = "partial" if est.partial else "complete"
    ds = test_dataset(data_root or default_data_root(), est.category, mode, est.num_points, limit=limit,
                      cache_dir=cache_dir)
    symmetry, unsigned = est.symmetry, False
    rows = []
    for i in tqdm(range(len(ds)), desc=f"confidence {est.category}-{mode}", disable=not progress):
        smp = ds.raw(i)
        t0 = time.perf_counter()
        try:
            r = est.predict_points(smp["points_m"])
        except EquiposeError:
            continue
        ms = (time.perf_counter() - t0) * 1e3
        R_gt = np.asarray(smp["rotation"], np.float64)
        rot = float(rotation_errors(r.rotation[None], R_gt[None], symmetry, unsigned_axis=unsigned)[0])
        axis = float(rotation_errors(r.rotation[None], R_gt[None], "continuous:z")[0])
        centre = float(np.linalg.norm(r.translation - np.asarray(smp["translation_m"], np.float64)) / smp["diag_m"])
        rows.append({"shape": int(smp["instance"]), "view": i, "prompt": "points", "up": "none", "rot_err": rot,
                     "axis_err": axis, "centre_err": centre,
                     "right": bool(rot <= RIGHT_DEG and centre <= RIGHT_DIAG), "confidence": float(r.confidence),
                     "ambiguous": bool(r.ambiguous), "occluded": 0.0, "ms": ms, **r.extras["evidence"]})
    return rows


MONOTONE = ("margin", "flip_margin", "axis_ratio", "top_taper", "bottom_cap")   # a larger margin, a body widening
                                                        # towards the posed opening or a closed posed bottom never
                                                        # lowers the confidence
AGAINST = ("plane_tilt", "plane_float", "plane_sink", "plane_rest", "top_cap", "own_axis_turn")   # a pose tilted
                                                        # on, floating above, sunk into or leaning on its support
                                                        # plane, whose opening shows a closed bottom, or whose axis
                                                        # a stage turned away from the network's own, is never more
                                                        # likely right


def _columns(features, names) -> list:
    """Column indices of ``names`` among ``features``."""
    return [j for j, f in enumerate(features) if f in names]


def _signs(features) -> dict:
    """``fit_logistic``'s sign bounds for ``features``: the ``MONOTONE`` weights kept ≥ 0, the ``AGAINST`` ones ≤ 0."""
    return {"nonnegative": _columns(features, MONOTONE), "nonpositive": _columns(features, AGAINST)}


def _fit(rows: list, features) -> tuple:
    """``fit_logistic`` of ``rows`` on ``features`` within their sign bounds (``_signs``)."""
    return fit_logistic(*feature_matrix(rows, features), **_signs(features))


def feature_matrix(rows: list, features, label: str = "right") -> tuple:
    """(X [n, F] the rows' ``features``, y [n] their ``label`` as 0/1)."""
    X = np.array([[row[f] for f in features] for row in rows], np.float64)     # [n, F]
    y = np.array([row[label] for row in rows], np.float64)                     # [n]
    return X, y


def fit_logistic(X: np.ndarray, y: np.ndarray, l2: float = L2, nonnegative=(), nonpositive=()) -> tuple:
    """Ridge logistic regression. Convention: X [n, F], y [n] in {0, 1} → (weights [F], bias) on the raw features
    (fitted on standardised ones, so the ridge treats every feature alike); the weights of the columns in
    ``nonnegative`` stay ≥ 0 (evidence that can only speak for the pose, such as a margin), those in ``nonpositive``
    ≤ 0 (evidence that can only speak against it)."""
    if X.ndim != 2 or len(X) != len(y) or len(np.unique(y)) < 2:
        raise ConfigError(f"logistic fit needs X [n, F] and both outcomes in y; got {X.shape}, {np.unique(y)}")
    mu, sd = X.mean(0), X.std(0)
    sd[sd < 1e-9] = 1.0
    Z = (X - mu) / sd                                                           # [n, F]

    def loss(p):
        w, b = p[:-1], p[-1]
        z = Z @ w + b
        nll = np.mean(np.logaddexp(0.0, z) - y * z)
        q = 1.0 / (1.0 + np.exp(-z)) - y                                       # dNLL/dz
        return nll + l2 * w @ w, np.append(Z.T @ q / len(y) + 2 * l2 * w, q.mean())

    bounds = [(0.0, None) if j in nonnegative else (None, 0.0) if j in nonpositive else (None, None)
              for j in range(X.shape[1])] + [(None, None)]
    p = minimize(loss, np.zeros(X.shape[1] + 1), jac=True, method="L-BFGS-B", bounds=bounds).x
    w = p[:-1] / sd
    return w, float(p[-1] - w @ mu)


def predict_logistic(X: np.ndarray, w: np.ndarray, b: float) -> np.ndarray:
    """[n] σ(b + X·w), the SDK's ``logistic``."""
    return logistic(X @ w + b)


def reliability(p: np.ndarray, y: np.ndarray, bins: int = 10) -> tuple:
    """([{"lo", "hi", "n", "mean_confidence", "right_rate"}], ECE) over equal-width confidence bins."""
    edges = np.linspace(0.0, 1.0, bins + 1)
    k = np.clip(np.digitize(p, edges) - 1, 0, bins - 1)
    table, ece = [], 0.0
    for i in range(bins):
        sel = k == i
        if not sel.any():
            continue
        mc, rr = float(p[sel].mean()), float(np.mean(y[sel]))
        table.append({"lo": float(edges[i]), "hi": float(edges[i + 1]), "n": int(sel.sum()), "mean_confidence": mc,
                      "right_rate": rr})
        ece += sel.mean() * abs(mc - rr)
    return table, float(ece)


def summarize(rows: list, p: np.ndarray) -> dict:
    """Held-out figures of confidences ``p`` [n] for ``rows``: AUROC, ECE, Brier, confident-wrong counts, and the
    same for the selection margin (the uncalibrated confidence) for comparison."""
    y = np.array([r["right"] for r in rows], bool)
    err = np.array([r["rot_err"] for r in rows])
    amb = np.array([r["ambiguous"] for r in rows], bool)
    margin = np.array([r["margin"] for r in rows])
    table, ece = reliability(p, y)
    _, ece_m = reliability(margin, y)
    wrong = (err > WRONG_DEG) & ~amb
    return {"n": int(len(rows)), "right_rate": float(y.mean()), "auroc": auroc(p, y), "ece": ece,
            "brier": float(np.mean((p - y) ** 2)), "confident_wrong": int(np.sum(wrong & (p > 0.5))),
            "margin_auroc": auroc(margin, y), "margin_ece": ece_m,
            "margin_confident_wrong": int(np.sum(wrong & (margin > 0.5))), "reliability": table}


def split_rows(rows: list) -> tuple:
    """(fit rows: even-numbered test shapes, held-out rows: odd-numbered ones)."""
    return [r for r in rows if r["shape"] % 2 == 0], [r for r in rows if r["shape"] % 2 == 1]


def grouped_log_loss(rows: list, features, folds: int = 5, label: str = "right", signs: dict | None = None) -> float:
    """Mean held-out log loss of the logistic model for ``label`` (0/1 per row) on ``features`` over ``folds`` folds
    of whole shapes; ``signs``: ``fit_logistic``'s sign bounds (default: the confidence's, ``_signs``)."""
    shapes = np.array([r["shape"] for r in rows])
    X, y = feature_matrix(rows, features, label)
    losses = []
    for k in range(folds):
        out = shapes % folds == k
        if not out.any() or out.all() or len(np.unique(y[~out])) < 2:
            continue
        w, b = fit_logistic(X[~out], y[~out], **(_signs(features) if signs is None else signs))
        p = np.clip(predict_logistic(X[out], w, b), 1e-6, 1 - 1e-6)
        losses.append(-np.mean(y[out] * np.log(p) + (1 - y[out]) * np.log(1 - p)))
    return float(np.mean(losses)) if losses else float("inf")


def choose_features(rows: list, features) -> list:
    """The feature set (the selection margin alone, the margins, or every feature) with the lowest shape-grouped
    cross-validated log loss on ``rows``: with few wrong results the full model overfits."""
    margins = [f for f in ("margin", "flip_margin") if f in features]
    sets = [features[:1] if not margins else margins[:1], margins, list(features)]
    sets = [list(c) for i, c in enumerate(sets) if c and c not in sets[:i]]
    return min(sets, key=lambda c: grouped_log_loss(rows, c))


RUNNER_UP_CANDIDATES = (0.05, 0.03, 0.02, 0.01, 0.005)   # selection margins tried, widest first
RUNNER_UP_MIN_RESULTS = 5


def first_flagging(values, rows: list, candidates, flagged, wrong_share: float) -> float:
    """The first of ``candidates`` whose flagged set (``flagged(values [n], t)`` → bool [n]) holds at least
    ``RUNNER_UP_MIN_RESULTS`` of ``rows`` and at least ``wrong_share`` wrong ones ("right" False), else 0."""
    values = np.asarray(values, np.float64)                                    # [n]
    wrong = ~np.array([bool(r["right"]) for r in rows], bool)                  # [n]
    for t in candidates:
        m = flagged(values, t)                                                 # [n]
        if m.sum() >= RUNNER_UP_MIN_RESULTS and wrong[m].mean() >= wrong_share:
            return t
    return 0.0


def runner_up_margin(rows: list) -> float:
    """The widest selection margin below which the results are wrong at least half the time (at least
    ``RUNNER_UP_MIN_RESULTS`` of them), else 0: below it another pose > 30° away fits as well, and the confidence stage
    flags the result ``ambiguous``. Rows need "margin" (as the stages left it) and "right"."""
    return first_flagging([r["margin"] for r in rows], rows, RUNNER_UP_CANDIDATES, lambda v, t: v < t, 0.5)


CLOSED_TOP_CANDIDATES = (0.05, 0.08, 0.1, 0.12, 0.15, 0.2)   # top_cap thresholds tried, lowest first
CLOSED_TOP_WRONG = 0.5                                     # ... the share of wrong results needed at or above one:
                                                           # more often wrong than right (as turned_top_cap)
OPEN_BOTTOM_WRONG = 0.5                                    # the same for open_bottom_cap


def closed_top_cap(rows: list) -> float:
    """The lowest ``top_cap`` at or above which the results are wrong at least ``CLOSED_TOP_WRONG`` of the time (at
    least ``RUNNER_UP_MIN_RESULTS`` of them), else 0: there the posed top shows a closed bottom, the object may stand
    the other way up, and the confidence stage flags the result ``ambiguous``. Rows need "top_cap" and "right"."""
    if not rows or "top_cap" not in rows[0]:
        return 0.0
    return first_flagging([r["top_cap"] for r in rows], rows, CLOSED_TOP_CANDIDATES, lambda v, t: v >= t,
                          CLOSED_TOP_WRONG)


TURNED_TOP_CANDIDATES = (0.02, 0.03, 0.05, 0.08, 0.1, 0.12, 0.15, 0.2)   # top_cap thresholds tried, lowest first


def turned_top_cap(rows: list) -> float:
    """The lowest ``top_cap`` at or above which the results under an up prior whose axis the network had the other
    way up (``own_axis_turn`` > ``TURNED``) are wrong at least half the time (at least ``RUNNER_UP_MIN_RESULTS`` of
    them), else 0: the confidence stage flags such results ``ambiguous`` (``turned_closed_top``). Rows need
    "up_given", "own_axis_turn", "top_cap" and "right"."""
    rows = [r for r in rows if r.get("up_given") and r.get("own_axis_turn", 0.0) > TURNED]
    return first_flagging([r["top_cap"] for r in rows], rows, TURNED_TOP_CANDIDATES, lambda v, t: v >= t, 0.5)


OPEN_BOTTOM_CANDIDATES = (0.12, 0.1, 0.08, 0.05, 0.03, 0.02)   # bottom_cap thresholds tried, highest first


def open_bottom_cap(rows: list) -> float:
    """The highest ``bottom_cap`` below which the results posed on their opening on the support plane
    (``plane_tilt`` > 0.5) are wrong at least ``OPEN_BOTTOM_WRONG`` of the time (at least ``RUNNER_UP_MIN_RESULTS`` of
    them), else 0: the end facing up reads open, so the object may stand the other way up, and the confidence stage
    flags such results ``ambiguous`` (``open_bottom_up``). Rows need "plane_tilt", "bottom_cap" and "right"."""
    rows = [r for r in rows if r.get("plane_tilt", 0.0) > 0.5 and "bottom_cap" in r]
    return first_flagging([r["bottom_cap"] for r in rows], rows, OPEN_BOTTOM_CANDIDATES, lambda v, t: v < t,
                          OPEN_BOTTOM_WRONG)


def choose_flags(fit: list) -> dict:
    """The ambiguity flags of a ``confidence_calibration`` entry, each chosen on the ``fit`` rows."""
    return {"runner_up_margin": runner_up_margin(fit), "closed_top_cap": closed_top_cap(fit),
            "turned_top_cap": turned_top_cap(fit), "open_bottom_cap": open_bottom_cap(fit)}


def flag_rows(rows: list, calibration: dict) -> list:
    """Copies of ``rows`` with "ambiguous" set where the confidence stage would flag them under ``calibration``
    (``runner_up_margin``, ``closed_top_cap``, ``turned_top_cap``, ``open_bottom_cap``) before it reads the
    evidence."""
    return [dict(r, ambiguous=1.0) if below_runner_up(r["margin"], calibration)
            or closed_top(r.get("top_cap", 0.0), calibration)
            or turned_closed_top(r.get("top_cap", 0.0), r.get("own_axis_turn", 0.0), bool(r.get("up_given")),
                                 calibration)
            or open_bottom_up(r.get("plane_tilt", 0.0), r.get("bottom_cap", 1.0), calibration) else dict(r)
            for r in rows]


def calibrate(rows: list, features=CONFIDENCE_FEATURES) -> tuple:
    """(metadata dict for ``confidence_calibration``, held-out summary, the rows as fitted: copies of ``rows``, those
    the stage will flag (``flag_rows``) flagged ``ambiguous``, the held-out ones with "p"). The flags
    (``choose_flags``) and the features (``choose_features``) are chosen on the fit rows alone; ``rows`` themselves
    are left as they are."""
    flags = choose_flags(split_rows(rows)[0])
    rows = flag_rows(rows, flags)
    fit, held = split_rows(rows)
    if not fit or not held:
        raise ConfigError("confidence calibration needs views of at least two test shapes")
    features = [f for f in features if all(f in r for r in rows) and np.ptp([r[f] for r in rows]) > 0]
    # (features a row set lacks, or that are constant, carry nothing)
    features = choose_features(fit, features)
    tabletop = rows[0]["prompt"] != "points"
    w, b = _fit(fit, features)
    p = predict_logistic(feature_matrix(held, features)[0], w, b)
    summary = summarize(held, p)
    for r, q in zip(held, p):
        r["p"] = float(q)
    meta = {"features": list(features), "weights": [round(float(v), 6) for v in w], "bias": round(b, 6),
            "definition": f"P(rotation within {RIGHT_DEG:g} deg modulo symmetry and centre within "
                          + (f"{RIGHT_M * 100:g} cm)" if tabletop else f"{RIGHT_DIAG:g} of the bbox diagonal)"),
            "fitted_on": f"{len(fit)} " + ("rendered occluded tabletop views" if tabletop else "ModelNet test "
                                          "samples") + f" (even-numbered shapes); held out {len(held)}",
            "held_out": {k: round(v, 4) if isinstance(v, float) else v for k, v in summary.items()
                         if k != "reliability"},
            **flags}
    return meta, summary, rows


def plot_reliability(summary: dict, path, title: str) -> None:
    """Reliability diagram (mean confidence vs right rate per bin, bin sizes as bars) as a PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = summary["reliability"]
    fig, ax = plt.subplots(figsize=(4.2, 4.2))
    ax.plot([0, 1], [0, 1], "k:", lw=1)
    ax.plot([b["mean_confidence"] for b in t], [b["right_rate"] for b in t], "o-", label="calibrated confidence")
    ax2 = ax.twinx()
    ax2.bar([(b["lo"] + b["hi"]) / 2 for b in t], [b["n"] for b in t], width=0.08, alpha=0.2, color="gray")
    ax2.set_ylabel("results per bin")
    ax.set_xlabel("confidence")
    ax.set_ylabel("share right (≤ 10°, ≤ 2 cm)")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    ax.set_title(f"{title}\nAUROC {summary['auroc']:.3f}, ECE {summary['ece']:.3f} (held out, n={summary['n']})",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def handle_summary(rows: list) -> dict:
    """Mug rows (with ``handle_truth_px``): how often ``handle_visible`` is said, its precision against the render's
    visible handle pixels (≥ 1 and ≥ 30), its recall (≥ 1 pixel), and the results whose handle was hidden (0 pixels)
    but called visible."""
    vis = [r for r in rows if r["handle_visible"]]
    shown = [r for r in rows if r["handle_truth_px"] >= 1]
    hidden = [r for r in rows if r["handle_truth_px"] == 0]
    return {"visible": len(vis),
            "precision_1px": sum(r["handle_truth_px"] >= 1 for r in vis) / max(len(vis), 1),
            "precision_30px": sum(r["handle_truth_px"] >= 30 for r in vis) / max(len(vis), 1),
            "recall_1px": sum(r["handle_visible"] for r in shown) / max(len(shown), 1),
            "hidden": len(hidden), "hidden_called_visible": sum(r["handle_visible"] for r in hidden)}


def _check(rows: list, model: str, json_path: str | None) -> int:
    """``--check``: the stored confidence of each row, scored on all of them (no fit)."""
    summary = summarize(rows, np.array([r["confidence"] for r in rows]))
    print(f"{pathlib.Path(model).name}: {len(rows)} results, right {summary['right_rate']:.3f}; stored confidence: "
          f"AUROC {summary['auroc']:.3f}, ECE {summary['ece']:.3f}, confident-wrong {summary['confident_wrong']}")
    if rows and "handle_truth_px" in rows[0]:
        summary["handle"] = h = handle_summary(rows)
        print(f"handle_visible on {h['visible']} results: precision {h['precision_1px']:.4f} (≥ 1 handle pixel), "
              f"{h['precision_30px']:.4f} (≥ 30); recall {h['recall_1px']:.3f}; hidden handles called visible "
              f"{h['hidden_called_visible']} of {h['hidden']}")
    if json_path:
        pathlib.Path(json_path).write_text(json.dumps({"summary": summary, "rows": rows}, indent=1))
    return 0


def _refresh_flags(rows: list, model: str, write: bool) -> int:
    """``--flags-only``: the file's stored calibration with its ambiguity flags (``choose_flags``) chosen
    again on the fit rows (even-numbered shapes); the weights stay as stored."""
    from equipose.core.metadata import decode_metadata
    from equipose.core.model_file import read_metadata_props
    stored = decode_metadata(read_metadata_props(model), model).get("confidence_calibration")
    if stored is None:
        raise ConfigError(f"{model} stores no confidence calibration to keep: fit one (drop --flags-only)")
    fit = split_rows(rows)[0]
    meta = {**stored, "features": list(stored["features"]), "weights": [float(w) for w in stored["weights"]],
            **choose_flags(fit),
            "flags_chosen_on": f"{len(fit)} rendered occluded tabletop views (even-numbered shapes); weights as fitted"}
    print(f"{pathlib.Path(model).name}: runner_up_margin {stored.get('runner_up_margin', 0.0)} → "
          f"{meta['runner_up_margin']}, closed_top_cap {stored.get('closed_top_cap', 0.0)} → {meta['closed_top_cap']}, "
          f"turned_top_cap {stored.get('turned_top_cap', 0.0)} → {meta['turned_top_cap']}, "
          f"open_bottom_cap {stored.get('open_bottom_cap', 0.0)} → {meta['open_bottom_cap']} "
          f"(chosen on {len(fit)} results; weights kept)")
    if write:
        from equipose.export.onnx_export import update_metadata_with_int8
        update_metadata_with_int8(model, confidence_calibration=meta)
    return 0


def main(argv=None) -> int:
    ap = fit_parser(__doc__, views=240)
    ap.add_argument("--limit", type=int, help="ModelNet models: first K test instances")
    ap.add_argument("--rows", help="fit on the rows of an earlier --json instead of rendering again")
    ap.add_argument("--plot", help="write the held-out reliability diagram (PNG) here")
    ap.add_argument("--without", default="", help="comma-separated evidence features to leave out of the fit")
    ap.add_argument("--flags-only", dest="flags_only", action="store_true",
                    help="keep the file's stored weights and only re-choose its ambiguity flags (runner_up_margin, "
                         "closed_top_cap, turned_top_cap, open_bottom_cap) on the fit rows")
    ap.add_argument("--standing-only", dest="standing_only", action="store_true",
                    help="render no open container upside down (the view set up to 0.40)")
    ap.add_argument("--check", action="store_true",
                    help="score the confidence the model file stores on these results instead of fitting a new one")
    ap.add_argument("--stages", type=json.loads, default=None,
                    help="stage options over the profile's, as JSON (PoseEstimator(stages=...)), e.g. "
                         "'{\"axis_centre\": {\"enabled\": true}}'")
    a = ap.parse_args(argv)
    from equipose import PoseEstimator
    if a.rows:
        rows = json.loads(pathlib.Path(a.rows).read_text())["rows"]
    else:
        from equipose.train.data.tabletop import TABLETOP
        est = PoseEstimator(a.model, stages=a.stages)
        rows = collect(est, a.views, a.seed, a.data_root, upside_down=False if a.standing_only else None) \
            if est.category in TABLETOP else \
            collect_modelnet(est, a.data_root, limit=a.limit)
    if a.check:
        return _check(rows, a.model, a.json)
    if a.flags_only:
        return _refresh_flags(rows, a.model, a.write)
    without = {f for f in a.without.split(",") if f}
    if without - set(CONFIDENCE_FEATURES):
        raise ConfigError(f"--without: unknown feature(s) {sorted(without - set(CONFIDENCE_FEATURES))}; features: "
                          f"{', '.join(CONFIDENCE_FEATURES)}")
    meta, summary, rows = calibrate(rows, [f for f in CONFIDENCE_FEATURES if f not in without])
    print(f"{pathlib.Path(a.model).name}: {len(rows)} results, right {summary['right_rate']:.2f}; held out: "
          f"AUROC {summary['auroc']:.3f} (margin {summary['margin_auroc']:.3f}), ECE {summary['ece']:.3f} "
          f"(margin {summary['margin_ece']:.3f}), confident-wrong {summary['confident_wrong']} "
          f"(margin {summary['margin_confident_wrong']})")
    print("weights:", dict(zip(meta["features"], meta["weights"])), "bias", meta["bias"])
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"calibration": meta, "summary": summary, "rows": rows}, indent=1))
    if a.plot:
        plot_reliability(summary, a.plot, pathlib.Path(a.model).stem)
    if a.write:
        from equipose.export.onnx_export import update_metadata_with_int8
        update_metadata_with_int8(a.model, confidence_calibration=meta)   # and a stand-alone int8 sibling
    return 0


if __name__ == "__main__":
    sys.exit(main())
