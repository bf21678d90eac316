"""Fit the ``flip_risk`` stage: the chance that a partial model's pose is turned by about a half turn, from how
clearly the stages before it decided, and the threshold at which a result is flagged ``ambiguous``.

    python -m equipose.train.evaluation.flip_risk --model sdk/models/car-partial.onnx [--views 4] [--shapes N]
        [--seed 1] [--flag-share 0.3] [--write] [--json F]

Renders partial views of the category's **training** shapes (seed 1 by default: other views than the training cache's;
the test set stays for ``equipose eval``), runs each through ``PoseEstimator`` with the stage reading only
(``{"threshold": "read"}``: its features as it sees them, ``flip_readings``, and the stages' own flags left as they
are). A view is *flipped* where its rotation error exceeds 150°. The logistic model (sign-bounded: a clearer margin,
lead or copy agreement never raises the risk, a stage's flag never lowers it) is fitted on one of three feature sets,
chosen by shape-grouped cross-validated log loss: the turn classifier's lead and the flip margin; those with the
selection margin and the stages' flag; all five. The threshold is the risk that flags ``--flag-share`` of the fitting
views. ``--write`` stores ``flip_risk`` {"features", "weights", "bias", "threshold", "flag_share", "fitted_on", "fit"}
in the model file.

Convention: angles in degrees; risks are probabilities; AUROC for "flipped" (1 = every flip ranked above the rest).
"""
from __future__ import annotations

import json
import pathlib
import sys

import numpy as np

from equipose.core.errors import ConfigError
from equipose.eval.metrics import FLIP_DEG, auroc, rotation_errors
from equipose.runtime.stages.flip_risk import FLIP_RISK_FEATURES
from equipose.train.evaluation.confidence import feature_matrix, fit_logistic, grouped_log_loss, predict_logistic
from equipose.train.evaluation.fit_cli import fit_parser

__all__ = ["collect", "choose_features", "fit", "summarize", "main"]

FEATURE_SETS = (("turn_margin", "flip_margin"), ("turn_margin", "flip_margin", "margin", "flagged"),
                FLIP_RISK_FEATURES)
RAISES = ("flagged",)                                    # a stage's flag never lowers the risk
LOWERS = ("turn_margin", "flip_margin", "margin", "agreement")   # a clearer decision never raises it
FOLDS = 5


def collect(model, views: int = 4, shapes: int | None = None, seed: int = 1, data_root=None, cache_dir=None,
            progress: bool = True) -> list:
    """Rows {"shape", "view", "rot_err", "flipped", features...} of the model's poses on rendered partial views of
    the category's training shapes (``shapes``: the first N; None: all), the flip_risk stage reading only."""
    from tqdm import tqdm

    from equipose.runtime.estimator import PoseEstimator
    from equipose.train.data.datasets import RenderedPartial
    from equipose.train.data.modelnet import default_data_root
    from equipose.train.data.render_cache import ensure_cache
    est = PoseEstimator(model, stages={"flip_risk": {"threshold": "read"}})
    if not est.spec.partial:
        raise ConfigError(f"{est.spec.name} is a complete-shape model; the flip risk is fitted on partial views")
    root = data_root or default_data_root()
    ds = RenderedPartial(ensure_cache(root, est.category, "train", cache_dir=cache_dir, views=views, limit=shapes,
                                      seed=seed, progress=progress), est.num_points, train=False)
    rows = []
    for i in tqdm(range(0, len(ds), 16), desc=f"flip risk {est.category}", disable=not progress):
        samples = [ds.raw(j) for j in range(i, min(i + 16, len(ds)))]
        results = est.predict_points_batch([s["points_m"] for s in samples])
        R = np.stack([r.rotation for r in results])                             # [b, 3, 3]
        err = rotation_errors(R, np.stack([s["rotation"] for s in samples]), est.symmetry)   # [b] degrees
        for j, (s, r, e) in enumerate(zip(samples, results, err)):
            rows.append({"shape": int(s["instance"]), "view": i + j, "rot_err": float(e),
                         "flipped": bool(e > FLIP_DEG), **r.extras["flip_readings"]})
    return rows


def _bounds(features) -> dict:
    """``fit_logistic``'s sign bounds: ``RAISES`` ≥ 0, ``LOWERS`` ≤ 0."""
    return {"nonnegative": [j for j, f in enumerate(features) if f in RAISES],
            "nonpositive": [j for j, f in enumerate(features) if f in LOWERS]}


def _fit(rows: list, features) -> tuple:
    return fit_logistic(*feature_matrix(rows, features, "flipped"), **_bounds(features))


def choose_features(rows: list) -> list:
    """The feature set of ``FEATURE_SETS`` (constant features dropped) with the lowest grouped log loss."""
    varying = {f for f in FLIP_RISK_FEATURES if np.ptp([r[f] for r in rows]) > 0}
    sets = []
    for s in FEATURE_SETS:
        c = [f for f in s if f in varying]
        if c and c not in sets:
            sets.append(c)
    if not sets:
        raise ConfigError("no flip-risk feature varies over these views (no turn classifier, flip templates or "
                          "selection margin to read)")
    return min(sets, key=lambda c: grouped_log_loss(rows, c, FOLDS, label="flipped", signs=_bounds(c)))


def summarize(flipped: np.ndarray, risk: np.ndarray, threshold: float) -> dict:
    """Flip rate, AUROC of ``risk`` for a flip, the share flagged at ``threshold`` and the flip rates of the
    flagged and unflagged views. ``flipped`` [n] bool, ``risk`` [n]."""
    flagged = risk >= threshold

    def rate(m):
        return float(flipped[m].mean()) if m.any() else None

    return {"n": int(len(risk)), "flip_rate": float(flipped.mean()), "auroc": float(auroc(risk, flipped)),
            "flagged_share": float(flagged.mean()), "unflagged_flip_rate": rate(~flagged),
            "flagged_flip_rate": rate(flagged)}


def fit(rows: list, flag_share: float = 0.3) -> tuple:
    """(``flip_risk`` metadata entry, summary on the fitting rows, the stages' own flags summarised alike)."""
    if not 0.0 < flag_share < 1.0:
        raise ConfigError(f"--flag-share must be in (0, 1), got {flag_share}")
    flipped = np.array([r["flipped"] for r in rows], bool)
    if flipped.all() or not flipped.any():
        raise ConfigError(f"the flip risk needs flipped and unflipped views; {int(flipped.sum())} of {len(rows)} "
                          "flipped: render more views (--views, --shapes)")
    features = choose_features(rows)
    w, b = _fit(rows, features)
    risk = predict_logistic(feature_matrix(rows, features, "flipped")[0], w, b)       # [n]
    threshold = float(np.quantile(risk, 1.0 - flag_share))
    summary = summarize(flipped, risk, threshold)
    stages = summarize(flipped, np.array([r["flagged"] for r in rows]), 0.5)
    entry = {"features": list(features), "weights": [round(float(v), 6) for v in w], "bias": round(float(b), 6),
             "threshold": round(threshold, 6), "flag_share": flag_share,
             "fitted_on": f"{len(rows)} rendered partial views of {len({r['shape'] for r in rows})} training shapes",
             "fit": {k: round(v, 4) if isinstance(v, float) else v for k, v in summary.items()}}
    return entry, summary, stages


def _line(label: str, s: dict) -> str:
    un = "-" if s["unflagged_flip_rate"] is None else f"{s['unflagged_flip_rate']:.3f}"
    return (f"{label}: flagged {s['flagged_share']:.2f}, flips among unflagged {un}, among flagged "
            f"{s['flagged_flip_rate'] or 0.0:.3f}")


def main(argv=None) -> int:
    ap = fit_parser(__doc__, views=4, seed=1)
    ap.add_argument("--shapes", type=int, help="the first N training shapes (default: all)")
    ap.add_argument("--flag-share", dest="flag_share", type=float, default=0.3,
                    help="share of the fitting views flagged ambiguous at the threshold")
    ap.add_argument("--cache-dir", dest="cache_dir", help="render cache folder")
    a = ap.parse_args(argv)
    rows = collect(a.model, a.views, a.shapes, a.seed, a.data_root, a.cache_dir)
    entry, summary, stages = fit(rows, a.flag_share)
    name = pathlib.Path(a.model).name
    print(f"{name}: {summary['n']} training views, flip rate {summary['flip_rate']:.3f}; features "
          f"{', '.join(entry['features'])}; AUROC {summary['auroc']:.3f}; threshold {entry['threshold']:.4f}")
    print(_line("  stages' flags", stages))
    print(_line("  flip risk    ", summary))
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"flip_risk": entry, "stages": stages, "rows": rows}, indent=1))
    if a.write:
        from equipose.export.onnx_export import update_metadata_with_int8
        update_metadata_with_int8(a.model, flip_risk=entry)
    return 0


if __name__ == "__main__":
    sys.exit(main())
