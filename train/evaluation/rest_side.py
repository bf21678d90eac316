"""Fit the thresholds of the stages that decide which way up an open container rests: ``rest_side`` (when should the
up prior stand it on its opening?) and, with ``--upright``, ``stand_upright`` (when should a pose without a prior that
stands it on its opening be stood upright?).

    python -m equipose.train.evaluation.rest_side --model sdk/models/bowl-tabletop.onnx [--upright] [--views 200]
        [--seed 0] [--write] [--json F]

Renders the confidence fit's tabletop views (``equipose.train.evaluation.confidence.occluded_views``, every
``UPSIDE_DOWN_EVERY``-th view standing on its opening) and predicts each with box and mask, the stage reading only
(``{"cap": "read"}``):
- ``rest_side``, under ``up="plane"``: chooses the lowest ``top_cap`` among ``CANDIDATES`` at which turning the pose
  over (where the network's own axis points down) fixes at least ``RATIO`` times as many upside-down results as it
  breaks upright ones, and breaks at most ``MAX_BROKEN`` of the upright ones; stored as ``upside_down_rest``;
- ``stand_upright`` (``--upright``), without a prior: among the results posed on their opening on the support plane,
  chooses the highest ``bottom_cap`` among ``UPRIGHT_CANDIDATES`` below which turning the pose upright fixes at least
  ``RATIO`` times as many standing results as it breaks upside-down ones, and breaks at most ``MAX_BROKEN`` of all
  results; stored as ``upright_rest``.

``--write`` stores {"cap", "fixes", "breaks", "fitted_on", ...} in the model file (and its int8 sibling); no threshold
qualifying leaves the file as it is.

``--upright --height`` fits ``stand_upright``'s centre height instead: on rendered views of the category's standing
*training* shapes (point clouds; the test shapes stay for measuring), the results posed on their opening give rows of
the true centre's height above the object's base against the stage's ``top_height`` reading; the median ratio is
merged into the file's ``upright_rest`` as ``height`` (the cap stays; re-fitting the cap keeps the height).

Convention: shares in [0, 1]; the truth's rest from the rendering ("standing" | "upside_down").
"""
from __future__ import annotations

import json
import pathlib
import sys

from equipose.core.errors import ConfigError
from equipose.train.evaluation.fit_cli import fit_parser

__all__ = ["CANDIDATES", "UPRIGHT_CANDIDATES", "RATIO", "MAX_BROKEN", "MIN_HEIGHT_ROWS", "HEIGHT_READINGS",
           "collect_readings", "choose_cap", "choose_upright_cap", "collect_heights", "fit_height", "report_height",
           "main"]

CANDIDATES = (0.05, 0.08, 0.1, 0.12, 0.15, 0.2)
RATIO = 10.0            # fixes per break at least
MAX_BROKEN = 0.01       # share of the upright results turned over at most
UPRIGHT_CANDIDATES = (0.12, 0.1, 0.08, 0.05, 0.03, 0.02)   # stand_upright: bottom_cap thresholds, highest first
MIN_HEIGHT_ROWS = 10    # stand_upright's height: fitted on at least this many results


def collect_readings(model, views: int, seed: int, data_root=None, progress: bool = True,
                     upright: bool = False) -> list:
    """Rows {"view", "prompt", "rest", **reading} of the stage's readings: ``rest_side``'s under ``up="plane"``
    ({"own_up", "top_cap"}), or with ``upright`` ``stand_upright``'s without a prior ({"bottom_cap"}, None for the
    results not posed on their opening on a support plane: one row per result)."""
    from equipose import PoseEstimator
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.tabletop import TABLETOP, tabletop_sources
    from equipose.train.evaluation.confidence import handle_parts, occluded_views, view_results

    stage, up, extra = ("stand_upright", None, "upright_reading") if upright else ("rest_side", "plane", "rest_reading")
    est = PoseEstimator(model, stages={stage: {"cap": "read"}})
    if est.category not in TABLETOP or not TABLETOP[est.category].upside_down:
        raise ConfigError(f"rest_side fits open containers ({', '.join(c for c, t in TABLETOP.items() if t.upside_down)}),"
                          f" not {est.category!r}")
    sources = tabletop_sources(data_root or default_data_root(), est.category, "test")
    parts = handle_parts(est, sources)
    rows = []
    for v, _, view, rest in occluded_views(sources, views, seed, False, parts, desc=f"rest_side {est.category}",
                                           progress=progress, upside_down=True):
        for prompt, _, r, _ in view_results(est, view, ups=(up,)):
            reading = r.extras.get(extra)
            if reading is not None:
                rows.append({"view": v, "prompt": prompt, "rest": rest, **reading})
            elif upright:                                                       # posed upright: nothing to turn
                rows.append({"view": v, "prompt": prompt, "rest": rest, "bottom_cap": None})
    return rows


HEIGHT_READINGS = {                 # stage → (its read-only options, the up priors, the result extra it reads into)
    "stand_upright": ({"cap": "read"}, (None,), "upright_reading"),
    "seat": ({"height": "read"}, (None, "plane"), "seat_reading"),
}


def collect_heights(model, views: int, seed: int, data_root=None, progress: bool = True,
                    stage: str = "stand_upright") -> list:
    """Rows {"view", "prompt", "up", "centre_height" (m: the true centre above the object's base), "top_height" (m:
    the stage's reading)} of the results where ``stage`` reads a standing training shape, box and mask prompts:
    ``stand_upright`` without a prior, where the pose stands it on its opening (what the stage turns); ``seat``
    without and with ``up="plane"``, where the pose stands it upright."""
    import numpy as np

    from equipose import PoseEstimator
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.tabletop import TABLETOP, tabletop_sources
    from equipose.train.evaluation.confidence import handle_parts, occluded_views, view_results

    read, ups, extra = HEIGHT_READINGS[stage]
    est = PoseEstimator(model, stages={stage: read})
    if est.category not in TABLETOP:
        raise ConfigError(f"{stage}'s height is fitted on tabletop models ({', '.join(TABLETOP)}), not "
                          f"{est.category!r}")
    sources = [src for src in tabletop_sources(data_root or default_data_root(), est.category, "train")
               if "points" in src[1]]                                           # the point-cloud shapes
    parts = handle_parts(est, sources)
    rows = []
    for v, s, view, _ in occluded_views(sources, views, seed, False, parts, desc=f"{stage} {est.category}",
                                        progress=progress, upside_down=False):
        base = -float(np.min(np.asarray(sources[s][1]["points"])[:, 2]))      # m: centre above the base, standing
        for prompt, up, r, _ in view_results(est, view, ups=ups):
            reading = r.extras.get(extra)
            if reading is not None and reading["top_height"] > 0.0:
                rows.append({"view": v, "prompt": prompt, "up": up or "none", "centre_height": base,
                             "top_height": reading["top_height"]})
    return rows


def fit_height(rows: list) -> dict | None:
    """{"height": the median of centre_height / top_height, "height_rows": n}, or None with fewer than
    ``MIN_HEIGHT_ROWS`` rows."""
    import numpy as np

    if len(rows) < MIN_HEIGHT_ROWS:
        return None
    share = np.array([r["centre_height"] / r["top_height"] for r in rows])
    return {"height": round(float(np.clip(np.median(share), 1e-3, 1.0)), 4), "height_rows": len(rows)}


def _first_qualifying(candidates, turns, fixable: list, breakable: list, max_breaks: float) -> tuple | None:
    """(threshold, fixes, breaks) for the first of ``candidates`` at which ``turns(row, c)`` turns at least ``RATIO``
    times as many ``fixable`` rows as ``breakable`` ones, at least one, and at most ``max_breaks`` of the latter."""
    for c in candidates:
        fixes = sum(turns(r, c) for r in fixable)
        breaks = sum(turns(r, c) for r in breakable)
        if fixes > 0 and fixes >= RATIO * breaks and breaks <= max_breaks:
            return c, fixes, breaks
    return None


def choose_cap(rows: list) -> dict | None:
    """{"cap", "fixes", "breaks", "upside_down", "standing"} for the lowest qualifying threshold, or None."""
    down = [r for r in rows if r["rest"] == "upside_down"]
    up = [r for r in rows if r["rest"] != "upside_down"]
    if not down or not up:
        return None
    found = _first_qualifying(CANDIDATES, lambda r, c: r["own_up"] < 0.0 and r["top_cap"] >= c, down, up,
                              MAX_BROKEN * len(up))
    return None if found is None else {"cap": found[0], "fixes": found[1], "breaks": found[2],
                                       "upside_down": len(down), "standing": len(up)}


def choose_upright_cap(rows: list) -> dict | None:
    """``stand_upright``: {"cap", "fixes", "breaks", "standing", "upside_down"} for the highest qualifying
    ``bottom_cap`` threshold over the results posed on their opening (``rows`` with a reading), or None."""
    posed = [r for r in rows if r["bottom_cap"] is not None]
    standing = [r for r in posed if r["rest"] != "upside_down"]                 # posed on its opening: wrong
    down = [r for r in posed if r["rest"] == "upside_down"]                     # on its opening, posed so: right
    found = _first_qualifying(UPRIGHT_CANDIDATES, lambda r, c: r["bottom_cap"] < c, standing, down,
                              MAX_BROKEN * len(rows))
    return None if found is None else {"cap": found[0], "fixes": found[1], "breaks": found[2],
                                       "standing": len(standing), "upside_down": len(down)}


def main(argv=None) -> int:
    ap = fit_parser(__doc__)
    ap.add_argument("--upright", action="store_true",
                    help="fit stand_upright (no prior: stand a pose on its opening upright) instead of rest_side")
    ap.add_argument("--height", action="store_true",
                    help="with --upright: fit the centre height of the results it turns (training shapes) instead of "
                         "the cap, merged into the file's upright_rest")
    a = ap.parse_args(argv)
    if a.height and not a.upright:
        raise ConfigError("--height fits stand_upright's centre height: add --upright")
    name = pathlib.Path(a.model).name
    if a.height:
        return _main_height(a, name)
    rows = collect_readings(a.model, a.views, a.seed, a.data_root, upright=a.upright)
    choice = choose_upright_cap(rows) if a.upright else choose_cap(rows)
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"choice": choice, "rows": rows}, indent=1))
    if choice is None:
        what = "standing results upright as it turns upside-down" if a.upright else \
            "upside-down results right as it turns upright"
        print(f"{name}: no threshold turns ≥ {RATIO:g}× as many {what} ones wrong; nothing written")
        return 0
    if a.upright:
        choice["fitted_on"] = f"{len(rows)} rendered occluded tabletop results without an up prior (seed {a.seed})"
        print(f"{name}: cap {choice['cap']}: fixes {choice['fixes']} standing results posed on their opening, breaks "
              f"{choice['breaks']} of the {choice['upside_down']} upside-down ones posed so ({len(rows)} results)")
        kept = _upright_rest(a.model) or {}
        choice.update({k: v for k, v in kept.items() if k.startswith("height")})   # a fitted height stays
    else:
        choice["fitted_on"] = f"{len(rows)} rendered occluded tabletop views under up='plane' (seed {a.seed})"
        print(f"{name}: cap {choice['cap']}: fixes {choice['fixes']} of {choice['upside_down']} upside-down results, "
              f"breaks {choice['breaks']} of {choice['standing']} upright ones")
    if a.write:
        from equipose.export.onnx_export import update_metadata_with_int8
        update_metadata_with_int8(a.model, **{"upright_rest" if a.upright else "upside_down_rest": choice})
    return 0


def _upright_rest(model) -> dict | None:
    """The model file's ``upright_rest`` entry (parsed), or None."""
    from equipose.core.model_file import read_metadata
    from equipose.runtime.stages.stand_upright import StandUprightStage
    return StandUprightStage.parse(read_metadata(model).get("upright_rest"), str(model))


def report_height(a, name: str, rows: list, posed: str, fitted_key: str) -> dict | None:
    """``fit_height`` of ``rows`` reported as the height fits' command lines do (``a``: their parsed arguments):
    ``--json`` written, the share printed (or why nothing is written), the fit stamped with what it was fitted on
    (``fitted_key``: ``posed`` names the results). None where too few results were posed so."""
    fit = fit_height(rows)
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"choice": fit, "rows": rows}, indent=1))
    if fit is None:
        print(f"{name}: {len(rows)} results {posed} (< {MIN_HEIGHT_ROWS}); render more views; nothing written")
        return None
    fit[fitted_key] = f"{len(rows)} rendered occluded results {posed} (seed {a.seed})"
    print(f"{name}: height {fit['height']} (median centre height per top height over {len(rows)} results)")
    return fit


def _main_height(a, name: str) -> int:
    rows = collect_heights(a.model, a.views, a.seed, a.data_root)
    fit = report_height(a, name, rows, "without an up prior posing a standing training shape on its opening",
                        "height_fitted_on")
    if fit is not None and a.write:
        entry = _upright_rest(a.model)
        if entry is None:
            raise ConfigError(f"{name} has no upright_rest cap: fit it first (--upright --write without --height)")
        from equipose.export.onnx_export import update_metadata_with_int8
        update_metadata_with_int8(a.model, upright_rest={**entry, **fit})
    return 0


if __name__ == "__main__":
    sys.exit(main())
