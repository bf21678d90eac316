"""Category-level post-processing of one network run: ICP re-scoring, calibration into the category frame, hypothesis
selection (then ``polish`` more ICP iterations on the chosen pose; or the up prior's, ``equipose.runtime.upright``,
with "up" given or read off a complete cloud's resting face, ``equipose.runtime.rest_facet``), exact SO(3), metres,
and the geometric stages. ICP's template is the predicted canonical shape, with ``densify`` plus the midpoints between
its neighbouring points (``equipose.runtime.template``).

Convention: ``outputs`` are the 4 ONNX outputs of a batch (``equipose.runtime.session.OUTPUT_NAMES``), ``b`` the item;
``prep.model_points`` [N, 3] model units, centred camera frame; ``up`` None or a unit [3] camera-frame direction.
Results map the category frame to the camera frame, translation in metres (``equipose.runtime.result``).
"""
from __future__ import annotations

import time

import numpy as np

from equipose.core.geometry import nearest_rotation
from equipose.runtime.frame_priors import apply_frame_priors
from equipose.runtime.copies import consensus_pose, undo_copies
from equipose.runtime.hypotheses import (apply_calibration, canonicalise_rotation, parse_symmetry, select_hypothesis,
                                         symmetric_distance_deg)
from equipose.runtime.refine import icp_multi, refine_hypotheses
from equipose.runtime.rest_facet import rest_facet_up
from equipose.runtime.result import PoseResult
from equipose.runtime.stages import apply_stages
from equipose.runtime.template import densify_template
from equipose.runtime.upright import select_upright
from equipose.runtime.visibility import VIEW_AMBIGUOUS_MARGIN, view_rescore

__all__ = ["finish_category"]


def finish_category(est, outputs: dict, b: int, prep, *, prefer=None, prefer_margin: float = 0.0, up=None) -> tuple:
    """Batch item ``b`` → (PoseResult without timings, selection ms). With ``est.copies`` K > 1 the outputs hold K
    rotated copies per object (rows b·K …, ``equipose.runtime.copies``): hypotheses of copy 0, the copies' mean shape,
    and their consensus (ICP-refined like the re-scored ones) in place of its nearest hypothesis, ranked first. With
    ``up`` the up prior selects (its own ICP, so the re-scoring and the tracking preference are not used);
    ``result.up`` records it. Models with metadata
    ``rest_facet`` and no ``up`` take it from the cloud's resting face near the selected pose's up axis; models with
    ``frame_priors`` then turn the pose onto the cloud's mirror plane / footprint (``result.frame_priors``)."""
    t0 = time.perf_counter()
    K = est.copies
    if K > 1:                                                                   # rotated copies: rows b·K .. b·K+K−1
        rows = slice(b * K, (b + 1) * K)
        Rk, tk = undo_copies(outputs["hypothesis_rotations"][rows], outputs["hypothesis_translations"][rows],
                             est.copy_rotations)                                # [K, 60, 3, 3], [K, 60, 3]
        sk = np.asarray(outputs["hypothesis_scores"][rows], np.float64)        # [K, 60]
        canon = np.asarray(outputs["canonical_shape"][rows], np.float64).mean(0)  # [M, 3] mean over the copies
        R_all, t_all, s_all = Rk[0], tk[0], sk[0].copy()                        # copy 0, the input as it is (writable)
        first = sk.argmin(1)                                                    # [K] each copy's best
        R_c, t_c, support = consensus_pose(Rk[np.arange(K), first], tk[np.arange(K), first], est.symmetry)
    else:
        R_all = outputs["hypothesis_rotations"][b]                              # [60, 3, 3]
        t_all = outputs["hypothesis_translations"][b]                           # [60, 3] model units
        s_all = outputs["hypothesis_scores"][b]                                 # [60]
        canon = np.asarray(outputs["canonical_shape"][b], np.float64)           # [M, 3] learned frame, model units
    rescore = bool(est.refine) and up is None
    icp_template = densify_template(canon, est.densify) if rescore else canon   # [M', 3] ICP's template
    if rescore:                                                                 # ICP re-scoring, learned frame
        R_all, t_all, s_all = refine_hypotheses(prep.model_points, icp_template, R_all, t_all, s_all, k=est.refine,
                                                iters=est.refine_iters, bidirectional=not est.partial)
        if K > 1:                                                               # the consensus, refined the same way
            R1, t1, r1 = icp_multi(prep.model_points, icp_template, R_c[None], t_c[None], iters=est.refine_iters,
                                   bidirectional=not est.partial)
            R_c, t_c, s_c = R1[0], t1[0], float(r1[0])
    if K > 1:        # the consensus takes the place of its nearest hypothesis and ranks first
        j = int(np.argmin(symmetric_distance_deg(R_c, R_all, est.symmetry)))
        s_c = s_c if rescore else s_all[j]                                      # its residual, or the network's
        others = np.delete(s_all, j)
        R_all[j], t_all[j] = R_c, t_c
        s_all[j] = s_c if not len(others) or s_c < others.min() else np.nextafter(others.min(), -np.inf)
    viewed = rescore and est.partial and est.visibility is not None
    if viewed:                                                                  # view-aware re-scoring
        s_all = view_rescore(prep, canon, R_all, t_all, s_all, k=est.refine + (K > 1), symmetry=est.symmetry,
                             exponent=est.visibility, copy_poses=Rk[np.arange(K), first] if K > 1 else None)
    dR, dt = est.calibration_rotation, est.calibration_translation
    every_point = prep.model_points if prep.cloud is None else prep.cloud      # [P, 3] the whole crop, model units
    R_cat, t_cat = apply_calibration(R_all, t_all, dR, dt)                      # [60, 3, 3], [60, 3]
    canon_cat = canon @ dR.T + dt                                               # [M, 3] category frame, model units
    up_source = None if up is None else "given"
    if up is None:
        sel = select_hypothesis(R_cat, t_cat, s_all, symmetry=est.symmetry, top_k=est.top_k, prefer=prefer,
                                prefer_margin=prefer_margin,
                                **({"ambiguous_margin": VIEW_AMBIGUOUS_MARGIN} if viewed else {}))
        if rescore and est.polish:                                              # more ICP on the chosen pose
            Rp, tp, _ = icp_multi(every_point, icp_template, R_all[sel.index][None], t_all[sel.index][None],
                                  iters=est.polish, bidirectional=not est.partial)
            Rp, tp = apply_calibration(Rp, tp, dR, dt)                          # [1, 3, 3], [1, 3] category frame
            R_cat[sel.index], t_cat[sel.index] = Rp[0], tp[0]
        R, t_model = nearest_rotation(R_cat[sel.index]), t_cat[sel.index]
        rest = est.metadata.get("rest_facet")
        if rest is not None:
            up = rest_facet_up(prep.model_points, R[:, 2], rest["tolerance_deg"])
            up_source = None if up is None else "rest_facet"
    if up is not None:
        sel, R, t_model = select_upright(prep.model_points, canon_cat, R_cat, t_cat, s_all, up, symmetry=est.symmetry,
                                         top_k=est.top_k, bidirectional=not est.partial,
                                         starts=[sel.index] if up_source == "rest_facet" else None)
        R = nearest_rotation(R)
    turned = None
    if est.metadata.get("frame_priors") is not None:                           # mirror plane / footprint
        R, turned = apply_frame_priors(every_point, R, est.metadata["frame_priors"],
                                       keep_up=up if up_source == "given" else None)
    t_m = prep.to_metres(t_model)                                               # [3] metres
    canon_obj = canon_cat * est.scale                                           # [M, 3] category frame, metres
    kind, axis, _ = parse_symmetry(est.symmetry)
    res = PoseResult(
        rotation=R, translation=t_m, score=sel.score, confidence=sel.confidence, ambiguous=sel.ambiguous,
        canonical_shape=canon_obj @ R.T + t_m, canonical_shape_object=canon_obj, hypothesis_index=sel.index,
        top_k=sel.top_k, symmetry=est.symmetry, symmetry_axis=None if kind == "none" else R[:, axis].copy(),
        rotation_canonical=canonicalise_rotation(R, est.symmetry), category=est.category,
        random_init=est.random_init, up=None if up is None else np.asarray(up, np.float64).copy(), up_source=up_source,
        frame_priors=turned, agreement=None if K == 1 else float(support.mean()))
    apply_stages(est.metadata, res, prep.model_points, t_model, canon_cat, up=up)  # flip, cylinder, handle
    return res, (time.perf_counter() - t0) * 1e3
