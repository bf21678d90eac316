"""``PoseEstimator``: an equipose ONNX model + the SDK pipeline (crop → FPS → ORT → selection → calibration).

Convention:
    Inputs are depth frames (see ``equipose.preprocess``) or metric points [P, 3] in the OpenCV camera frame. The model is
    run on ``(p − centroid) / scale`` (model units, FPS-ordered to its N points); its hypotheses are calibrated into
    the category frame (metadata δR, δt), the best one is selected, and translations are mapped back to metres:
    ``t_m = t_model · scale + centroid``. Results are ``PoseResult`` (rotation category → camera, translation metres).
    Timings are milliseconds (``time.perf_counter``).
"""
from __future__ import annotations

import os
import time

import numpy as np

from equipose import preprocess as _crop
from equipose.core.errors import ConfigError, EquiposeError, InvalidPointsError, ModelFormatError, RegionError
from equipose.core.metadata import decode_metadata
from equipose.core.parallel import MAX_WORKERS, kernel_workers, run_parts, single_thread_blas, split_ranges
from equipose.core.presets import ModelConfig, total_macs
from equipose.runtime.instance import INSTANCE_ITERS, build_instance_model
from equipose.runtime.instance_clusters import (SEE_THROUGH_MAX, choose_cluster, fit_shares, other_cluster_gates,
                                                see_through_share)
from equipose.runtime.kernels import load_kernels
from equipose.runtime.pipeline import Pipeline
from equipose.runtime.profiles import merge_stage_options, profile_options
from equipose.runtime.result import FrameError, PoseResult
from equipose.runtime.spec import ModelSpec
from equipose.runtime.stage import stage_metadata_keys
from equipose.runtime.upright import check_up, per_object_up, resolve_support_plane
from equipose.models import resolve_model_file
from equipose.runtime.session import INPUT_NAME, OUTPUT_NAMES, GraphIO, check_io, open_session, run_in_chunks

__all__ = ["PoseEstimator", "INPUT_NAME", "OUTPUT_NAMES", "LIGHT_MODEL_MACS"]

LIGHT_MODEL_MACS = 1e9      # below this per object, a single object runs on one onnxruntime thread (adaptive_threads)


def _ms(t0: float) -> float:  # milliseconds since t0
    return (time.perf_counter() - t0) * 1e3


class PoseEstimator:
    """Category-level 6D pose from depth with an equipose ONNX model (CPU, onnxruntime).

    Args:
        model_path: an ``.onnx`` file written by ``equipose export``, or a shipped model's name (``equipose models``).
        threads: the thread budget (None = the core count): onnxruntime's intra-op threads, and how many parts run
            side by side (batch parts, the starts of one ICP call; ``equipose.core.parallel``).
        adaptive_threads: run a light model (< ``LIGHT_MODEL_MACS`` per object: every edge preset) on single-thread
            sessions: one object on one, a batch (objects × rotated copies) split into one part per thread of the
            budget, the parts run side by side. Hundreds of small kernels gain little from a second thread inside
            each kernel, and two parts side by side take about 0.7× the time of one 2-thread run (docs/benchmarks.md,
            v0.28). Attribute ``single_thread``: whether it applies.
        crop_options: defaults for ``equipose.preprocess.crop_points`` (e.g. ``{"max_depth": 2.0}``).
        top_k: hypotheses listed in each result.
        refine: ICP re-scoring (``equipose.runtime.refine``) of the ``refine`` best hypotheses against the predicted
            canonical shape, re-ranked by residual (0 = the network's argmin). "auto" (default): what the file was
            calibrated for (metadata ``refine_calibration``, ``equipose calibrate --model M --refine K``), else 0.
        refine_iters, polish: ICP iterations per refined hypothesis (default: the file's, else 10), and on the selected
            pose after re-scoring (0 = none; "auto": the file's, ``equipose calibrate --model M --polish N``, else 0).
        densify: the ICP template gains the midpoints to each canonical point's ``densify`` nearest neighbours
            (``equipose.runtime.template``; 0 = the predicted shape as it is; "auto": the file's, ``equipose calibrate
            --model M --densify N``, when re-scoring runs).
        copies: rotated input copies per object (``equipose.runtime.copies``): the network runs on ``copies`` turned
            copies of each object in one batch; the pose starts from their consensus and is refined against their
            mean canonical shape (1 = off). "auto" (default): what the file was calibrated for (metadata
            ``refine_calibration``, ``equipose calibrate --model M --copies K``) when its re-scoring is used, else 1.
        visibility: exponent of the view-aware re-scoring of partial views (``equipose.runtime.visibility``; None =
            off). "auto" (default): the file's (``equipose calibrate --model M --visibility E``) when re-scoring runs.
        model_points: instance-level mode (``equipose.runtime.instance``): [M, 3] metres of the object's own model
            (CAD frame); results are that model's pose (camera ← CAD), found by ICP of the ``instance_k`` best
            hypotheses (``instance_iters`` point-to-plane iterations) against the model points instead of the
            predicted shape.

    Attribute ``runner``: None (onnxruntime, ``run_model``) or a callable with ``run_model``'s contract
    (model points [B, N, 3] float32 → the 4 output arrays) used in its place by every ``predict*`` call; ``equipose
    bench`` swaps in torch eager and ICP-60 this way, so all backends share one pre/post-processing path.

    Raises ``ModelFormatError`` (missing file, not ONNX, not an equipose model, wrong inputs/outputs),
    ``ModelVersionError`` (metadata format mismatch), ``MetadataError`` (missing/malformed keys).
    """

    def __init__(self, model_path, threads: int | None = None, *, crop_options: dict | None = None, top_k: int = 5,
                 refine: int | str = "auto", refine_iters: int | None = None, copies: int | str = "auto",
                 visibility: float | str | None = "auto", polish: int | str = "auto",
                 densify: int | str = "auto", adaptive_threads: bool = True, profile: str = "default",
                 stages: dict | None = None, model_points=None, instance_k: int = 10,
                 instance_iters: int = INSTANCE_ITERS):
        path = resolve_model_file(model_path)
        if threads is not None and (not isinstance(threads, int) or threads < 0):
            raise ConfigError(f"threads must be None or a non-negative int, got {threads!r}")
        self.path = path
        self.kernels_s = load_kernels()                 # compiled geometry: compiled or loaded before any frame
        self.session = open_session(path, threads)
        props = dict(self.session.get_modelmeta().custom_metadata_map)
        self.metadata = decode_metadata(props, source=path.name)
        self.spec = ModelSpec.from_metadata(self.metadata, path.name)         # unsupported symmetry → MetadataError
        self.runner = None
        self.category = self.spec.category
        self.partial = self.spec.partial
        self.num_points = self.spec.num_points
        self.num_canonical_points = int(self.metadata["num_canonical_points"])
        self.scale = self.spec.scale
        self.symmetry = self.spec.symmetry
        self.random_init = self.spec.random_init
        self.handle = self.metadata.get("handle")                               # [3] category frame, or None
        if isinstance(top_k, bool) or not isinstance(top_k, int) or top_k < 1:
            raise ConfigError(f"top_k must be an int ≥ 1 (hypotheses listed per result), got {top_k!r}")
        self.top_k = int(top_k)
        self.profile = profile
        explicit = {"rescore": {"k": refine, "iters": "auto" if refine_iters is None else refine_iters,
                                "densify": densify},
                    "copies": {"count": copies}, "view": {"exponent": visibility}, "polish": {"iters": polish}}
        self.stage_options = merge_stage_options(profile_options(profile, path), explicit, stages)
        if model_points is not None and copies not in ("auto", 1):
            raise ConfigError("rotated input copies (copies > 1) do not apply in instance-level mode (model_points): "
                              "leave copies='auto' or 1")
        self.crop_options = _crop.check_crop_options(crop_options or {})
        # the model reads N FPS-ordered points: a crop of 4·N (≥ 1024) keeps FPS coverage and bounds crop/FPS cost
        self.crop_options.setdefault("max_points", max(1024, 4 * self.num_points))
        self.static_batch = check_io(self.session, path.name, self.num_points)
        self.graph_io = GraphIO(self.session, self.metadata, path.name)        # neighbourhoods in, scores added
        macs = total_macs(ModelConfig.from_dict(self.metadata["model_config"]), partial=self.partial)
        self.single_thread = bool(adaptive_threads) and threads != 1 and macs < LIGHT_MODEL_MACS
        self.workers = max(1, min(threads or os.cpu_count() or 1, MAX_WORKERS))   # parts side by side, at most
        parallel = self.workers if self.single_thread else 0
        self._single_sessions = [open_session(path, 1) for _ in range(parallel)]   # ≈ 20 ms each off the first call
        self.instance = None
        self._build_pipeline()
        if model_points is not None:
            self.instance = build_instance_model(self, model_points, k=instance_k, iters=instance_iters)
            self._build_pipeline()

    def _build_pipeline(self, calibration=None) -> None:
        """(Re)build the stage pipeline from the spec and the options, and the attributes that report it.
        ``calibration``: (δR, δt) set on the estimator, or None for the file's (the re-scoring's when it runs)."""
        mode = "category" if self.instance is None else "instance"
        self.pipeline = Pipeline.build(self.spec, self.stage_options, mode,
                                       {"instance": self.instance, "calibration": calibration, "threads": self.workers})
        rescore, rcal = self.pipeline.get("rescore"), self.spec.refine_calibration
        if calibration is None:
            calibration = (rcal["rotation"], rcal["translation"]) if (rescore and rcal) else self.spec.calibration
        self.calibration_rotation, self.calibration_translation = calibration
        self.refine = rescore.k if rescore else 0
        self.refine_iters = rescore.iters if rescore else int((rcal or {}).get("iters", 10))
        self.densify = rescore.densify if rescore else 0
        self.polish = self.pipeline.get("polish").iters if "polish" in self.pipeline else 0
        view = self.pipeline.get("view")
        self.visibility = None if view is None else view.exponent
        copies = self.pipeline.get("copies")
        self.copies = 1 if copies is None else copies.count
        self.copy_rotations = np.eye(3)[None] if copies is None else copies.rotations   # [K, 3, 3]
        self._pipeline_inputs = self._stage_inputs()

    def _stage_inputs(self) -> tuple:
        """What the pipeline was built from that callers may change on the estimator afterwards: the optional
        metadata keys the stages read, the symmetry and the calibration (a change rebuilds it on the next call)."""
        keys = tuple(id(self.metadata.get(k)) for k in stage_metadata_keys())
        return keys + (id(self.calibration_rotation), id(self.calibration_translation), self.symmetry)

    def _current_pipeline(self) -> Pipeline:
        if self._stage_inputs() != self._pipeline_inputs:                      # attributes changed since the build
            self.spec = ModelSpec.from_metadata({**self.metadata, "symmetry": self.symmetry}, self.path.name)
            self._build_pipeline((self.calibration_rotation, self.calibration_translation))
        return self.pipeline

    @property
    def pipeline_info(self) -> list:
        """The stages this estimator runs, in order, with their settings (JSON-ready)."""
        return self.pipeline.info()

    def uses_single_thread(self, batch: int) -> bool:
        """Whether a run of ``batch`` objects goes to one 1-thread session (``adaptive_threads``; larger batches run
        in parts side by side, one per thread of the budget)."""
        return self.single_thread and (batch == 1 or len(self._single_sessions) == 1)

    def __repr__(self):
        return (f"PoseEstimator({self.path.name!r}, category={self.category!r}, N={self.num_points}, "
                f"scale={self.scale} m/unit, symmetry={self.symmetry!r}, random_init={self.random_init})")

    @property
    def info(self) -> dict:
        """Model facts from the metadata (JSON-ready)."""
        keys = ("category", "preset", "num_points", "num_canonical_points", "scale", "partial", "symmetry",
                "random_init", "equipose_format", "equipose_version", "training", "metrics")
        return {k: self.metadata[k] for k in keys}

    def run_model(self, model_points: np.ndarray) -> dict:
        """Raw ONNX run. Convention: ``model_points`` [B, N, 3] float32 model units → dict of the 4 outputs
        (``OUTPUT_NAMES``; a format-2 graph's neighbourhoods and hypothesis scores computed by ``GraphIO``)."""
        x = np.ascontiguousarray(model_points, dtype=np.float32)
        if x.ndim != 3 or x.shape[1:] != (self.num_points, 3):
            raise InvalidPointsError(f"model input must be [B, {self.num_points}, 3], got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise InvalidPointsError("model input contains NaN/Inf")
        if self.static_batch is not None and x.shape[0] != self.static_batch:   # fixed-batch export: loop
            parts = [self.run_model(x[i:i + 1]) for i in range(x.shape[0])]
            return {k: np.concatenate([p[k] for p in parts]) for k in OUTPUT_NAMES}
        if self.uses_single_thread(x.shape[0]):
            return self._run_session(self._single_sessions[0], x)
        parts = split_ranges(x.shape[0], len(self._single_sessions))
        if len(parts) < 2:
            return self._run_session(self.session, x)
        outs = run_parts(self._run_session, [(sess, x[a:b], 1) for sess, (a, b) in zip(self._single_sessions, parts)])
        return {k: np.concatenate([o[k] for o in outs]) for k in OUTPUT_NAMES}  # onnxruntime releases the GIL

    def _run_session(self, session, x: np.ndarray, workers: int | None = None) -> dict:
        """One onnxruntime run of ``x`` [B, N, 3] on ``session`` → the 4 ``OUTPUT_NAMES`` arrays; ``workers``: the
        parts its hypothesis scores may take side by side (default the estimator's; 1 when the runs themselves
        already go side by side)."""
        io = self.graph_io
        feeds = io.feeds(x)                                                     # points (+ neighbourhoods)
        try:
            outs = session.run(io.outputs, feeds)
        except Exception as e:  # onnxruntime's own exception types (Fail, InvalidArgument, RuntimeException)
            raise ModelFormatError(f"onnxruntime could not run {self.path.name} on input {x.shape} "
                                   f"({type(e).__name__}: {str(e).splitlines()[0][:200]}); the model file may be "
                                   "damaged or not follow the equipose contract — re-export it") from None
        with kernel_workers(self.workers if workers is None else workers):      # (+ hypothesis scores, in parts)
            return io.complete(dict(zip(io.outputs, outs)), x)

    def _finish(self, outputs: dict, b: int, prep: "_crop.PreparedPoints", *, prefer: int | None = None,
                prefer_margin: float = 0.0, up=None, crop: dict | None = None, support_plane=None) -> tuple:
        """Outputs of batch item ``b`` → (PoseResult without timings, selection ms)."""
        if self.instance is not None and up is not None:
            raise ConfigError("the up prior does not apply in instance-level mode (model_points): leave up=None")
        with kernel_workers(self.workers), single_thread_blas():                # multi-start ICP side by side
            return self._current_pipeline().run(outputs, b, prep, prefer=prefer, prefer_margin=prefer_margin, up=up,
                                                support_plane=support_plane,
                                                category=self.category, top_k=self.top_k, crop=crop)

    def predict_points(self, points, *, up=None) -> PoseResult:
        """Pose of one object from its points.

        Convention: ``points`` [P, 3] metres, camera frame (P ≥ 64; NaN/Inf rejected); ``up`` None or the camera-frame
        up direction [3] (the up prior, ``equipose.runtime.upright``). Returns ``PoseResult``.
        Raises ``InvalidPointsError``, ``TooFewPointsError``, ``ConfigError`` (bad ``up``).
        """
        return self.predict_points_batch([points], up=up)[0]

    def predict_points_batch(self, point_sets, *, up=None) -> list:
        """Poses of several objects in one onnxruntime run. Convention: a list of [P_i, 3] metres → list of results;
        ``up``: None, one camera-frame direction [3] for all, or a list with one (or None) per object."""
        if isinstance(point_sets, np.ndarray) and point_sets.ndim == 2:
            raise InvalidPointsError("predict_points_batch takes a list of [P, 3] arrays; use predict_points for one")
        ups = per_object_up(up, len(point_sets))
        t0 = time.perf_counter()
        preps = [_crop.prepare_points(p, self.num_points, self.scale) for p in point_sets]
        if not preps:
            return []
        fps_ms = _ms(t0) / len(preps)
        return self._infer(preps, [None] * len(preps), [fps_ms] * len(preps), [0.0] * len(preps),
                           [len(_crop.check_points(p)) for p in point_sets], ups=ups)

    def _infer(self, preps, crops, fps_ms, crop_ms, counts, prefer=None, prefer_margin=0.0, ups=None,
               support_planes=None) -> list:
        t0 = time.perf_counter()
        copies = self._current_pipeline().get("copies")
        with kernel_workers(self.workers):                                      # the copies' FPS side by side
            x = copies.input_batch(preps) if copies is not None else \
                np.stack([p.model_points for p in preps])                       # [B·K, N, 3] or [B, N, 3]
        outputs = run_in_chunks(self.runner or self.run_model, x)                # ≤ RUN_CHUNK inputs per run
        inf_ms = _ms(t0)
        results = []
        for b, prep in enumerate(preps):
            pref = None if prefer is None else prefer[b]
            res, sel_ms = self._finish(outputs, b, prep, prefer=pref, prefer_margin=prefer_margin,
                                       up=None if ups is None else ups[b],
                                       support_plane=None if support_planes is None else support_planes[b],
                                       crop=None if crops[b] is None else crops[b].diagnostics)
            res.num_points, res.points_centre = int(counts[b]), prep.centre_m.copy()
            res.crop = {} if crops[b] is None else dict(crops[b].diagnostics)
            res.timings = {"crop": crop_ms[b], "fps": fps_ms[b], "inference": inf_ms, "selection": sel_ms,
                           "total": crop_ms[b] + fps_ms[b] + inf_ms + sel_ms, "batch": len(preps),
                           "stages": res.timings.get("stages", {})}
            results.append(res)
        return results

    def predict(self, depth, K, box=None, mask=None, depth_unit="mm", *, image_size=None, up=None,
                **crop_options) -> PoseResult:
        """Pose of one object in a depth frame.

        Convention: ``depth`` [H, W] (uint16 mm by default; declare other units), ``K`` [3, 3] (for ``image_size``
        (W, H) if given, else for the frame), ``box`` (x, y, w, h) pixels and/or ``mask`` [H, W] bool; ``up``: None,
        "plane" (the frame's support plane normal; ``result.up`` stays None when there is none) or a camera-frame
        direction [3] — the up prior for objects standing in their rest pose (``equipose.runtime.upright``).
        Returns ``PoseResult`` with ``timings`` (crop, fps, inference, selection, total ms).
        Raises the typed errors of ``equipose.preprocess`` (depth, intrinsics, region, too few points).
        """
        regions = [{"box": box, "mask": mask}]
        return self.predict_batch(depth, K, regions=regions, depth_unit=depth_unit, image_size=image_size, up=up,
                                  **crop_options)[0]

    def crop(self, depth, K, box=None, mask=None, depth_unit="mm", *, image_size=None, **crop_options):
        """``equipose.preprocess.crop_points`` with this estimator's crop defaults. Returns ``CropResult``."""
        opts = _crop.check_crop_options({**self.crop_options, **crop_options})
        return _crop.crop_points(depth, K, box=box, mask=mask, depth_unit=depth_unit, image_size=image_size, **opts)

    def predict_batch(self, depth, K, boxes=None, masks=None, depth_unit="mm", *, regions=None, image_size=None,
                      return_errors: bool = False, prefer=None, prefer_margin: float = 0.0, up=None,
                      **crop_options) -> list:
        """Poses of several objects in one frame, with a single onnxruntime run of batch B.

        Convention: ``boxes`` list of (x, y, w, h) and/or ``masks`` list of [H, W] bool (same length if both), or
        ``regions`` list of ``{"box": ..., "mask": ...}``. Returns a list of ``PoseResult`` in region order. With
        ``return_errors=True`` an object whose crop fails yields a ``FrameError`` (object_id = its position) instead of
        raising; frame-level errors (depth, intrinsics) still raise. ``up``: as in ``predict``, for every object.
        """
        up = check_up(up)
        if regions is None:
            regions = _crop.check_regions(boxes, masks)                         # [{box, mask}] per object
        if not regions:
            return []
        if any(not isinstance(r, dict) or (r.get("box") is None and r.get("mask") is None) for r in regions):
            raise RegionError("every object needs a box or a mask: a whole-frame crop would take the table and the "
                              "background for the object. Pass box=(x, y, w, h) or mask=..., or call predict_auto "
                              "to find the objects on a table (a frame holding only the object: mask=depth > 0)")
        t0 = time.perf_counter()
        depth_m = _crop.depth_to_metres(depth, depth_unit)                      # [H, W] m — validates once per frame
        Kf = _crop.check_intrinsics(K, depth_m.shape, image_size)               # [3, 3]
        opts = _crop.check_crop_options({**self.crop_options, **crop_options})
        wants_plane = opts.get("remove_support_plane")
        if wants_plane is None:
            wants_plane = any(r.get("box") is not None and r.get("mask") is None for r in regions)
        plane = opts.get("support_plane")
        given = plane is not None
        if plane is None:          # one plane fit per frame (about 0.1 ms): the crop, the up prior, the confidence
            plane = _crop.find_support_plane(depth_m, Kf)
            if wants_plane and plane is None:
                crop_options = {**crop_options, "remove_support_plane": False}
        shared_ms = _ms(t0) / len(regions)
        preps, crops, fps_ms, crop_ms, counts, slots, out, prefs = [], [], [], [], [], [], [None] * len(regions), []
        levels, owns = [], []                        # each kept object's support plane, and its crop's plane option
        for i, reg in enumerate(regions):
            try:
                t1 = time.perf_counter()
                level = plane if given else _crop.local_support_plane(depth_m, Kf, plane,
                                                                      _crop.region_bounds(reg, depth_m.shape))
                own = {"support_plane": level} if wants_plane and level is not None and not given else {}
                c = self.crop(depth_m, Kf, box=reg.get("box"), mask=reg.get("mask"), depth_unit="m",
                              prevalidated=True, **crop_options, **own)
                t2 = time.perf_counter()
                prep = _crop.prepare_points(c.points, self.num_points, self.scale)
                t3 = time.perf_counter()
            except EquiposeError as e:
                if not return_errors:
                    raise
                out[i] = FrameError.from_exception(-1, e, object_id=i)
                continue
            preps.append(prep)
            crops.append(c)
            levels.append(level)
            owns.append(own)
            counts.append(len(c.points))
            slots.append(i)
            crop_ms.append(shared_ms + (t2 - t1) * 1e3)
            fps_ms.append((t3 - t2) * 1e3)
            prefs.append(None if prefer is None else prefer[i])
        if preps:
            supports = [resolve_support_plane(lv, c.points) for lv, c in zip(levels, crops)]  # None: no plane under it
            support_ups = [None if s is None else s[0] for s in supports]
            results = self._infer(preps, crops, fps_ms, crop_ms, counts, prefer=prefs, prefer_margin=prefer_margin,
                                  ups=support_ups if isinstance(up, str) else [up] * len(preps),
                                  support_planes=supports)
            for i, r in zip(slots, results):
                out[i] = r
            if self.instance is not None:                  # the pose against the frame; the box's other clusters
                for j, i in enumerate(slots):
                    out[i] = self._check_instance(depth_m, Kf, regions[i], out[i], crops[j],
                                                  {**crop_options, **owns[j]}, levels[j], opts)
        return out

    def _check_instance(self, depth_m, K, region: dict, result: PoseResult, crop, crop_options: dict, level,
                        opts: dict) -> PoseResult:
        """Instance mode: the pose checked against its crop and the depth frame (``equipose.runtime.instance_clusters``:
        result extras ``model_fit``, the share of the crop's points within 5 mm of the posed model, and
        ``see_through``, the share of its visible points the camera sees through). A box crop (no mask) that found
        several depth clusters and whose pose is seen through is cropped again beyond and before the chosen cluster,
        each crop posed, and the pose seen through least kept; then extras ``clusters_tried``: [{"depth_m", "points",
        "fit", "see_through"} (+ the re-crop's "min_depth", "max_depth" crop options)] per candidate, the box-evidence
        crop first, and ``cluster_choice``: "box" or "fit". Every re-crop shares the first crop's ``crop_options``
        (its own support plane included) and is posed on that plane, ``level`` (no up prior: instance mode takes
        none); ``opts``: the frame's checked crop options (depth range)."""
        t0 = time.perf_counter()
        model = self.instance.verify_m
        cands, crops, gates = [result], [crop], [{}]
        seen = [see_through_share(result.rotation, result.translation, model, depth_m, K)]
        several = region.get("mask") is None and crop.diagnostics.get("clusters", 0) >= 2
        if several and seen[0] > SEE_THROUGH_MAX:
            for gate in other_cluster_gates(crop.points, opts.get("min_depth", 0.1), opts.get("max_depth", 10.0)):
                try:
                    c = self.crop(depth_m, K, box=region["box"], depth_unit="m", prevalidated=True,
                                  **{**crop_options, **gate})
                    prep = _crop.prepare_points(c.points, self.num_points, self.scale)
                    support = resolve_support_plane(level, c.points)                # None: no plane under it
                    r = self._infer([prep], [c], [0.0], [0.0], [len(c.points)], support_planes=[support])[0]
                except EquiposeError:                                           # nothing left there: no candidate
                    continue
                cands.append(r)
                crops.append(c)
                gates.append({k: round(v, 4) for k, v in gate.items()})
                seen.append(see_through_share(r.rotation, r.translation, model, depth_m, K))
        shares = fit_shares(np.stack([r.rotation for r in cands]), np.stack([r.translation for r in cands]), model,
                            [c.points for c in crops], tree=self.instance.verify_tree)   # [C]
        best = choose_cluster(seen)
        chosen = cands[best]
        chosen.extras["model_fit"] = round(float(shares[best]), 4)
        chosen.extras["see_through"] = round(float(seen[best]), 4)
        if several:
            chosen.extras["clusters_tried"] = [{"depth_m": round(float(np.median(c.points[:, 2])), 4),
                                                "points": int(len(c.points)), "fit": round(float(f), 4),
                                                "see_through": round(float(v), 4), **g}
                                               for c, f, v, g in zip(crops, shares, seen, gates)]
            chosen.extras["cluster_choice"] = "box" if best == 0 else "fit"
        extra = _ms(t0)
        chosen.timings = {**result.timings, "model_check": extra, "total": result.timings["total"] + extra}
        return chosen

    def predict_auto(self, depth, K, depth_unit="mm", *, image_size=None, return_errors: bool = False,
                     auto_options: dict | None = None, up=None, **crop_options) -> list:
        """Tabletop auto crop (``equipose.preprocess.auto_masks``) then ``predict_batch`` on every mask found."""
        masks = _crop.auto_masks(depth, K, depth_unit=depth_unit, image_size=image_size, **(auto_options or {}))
        return [] if not masks else self.predict_batch(depth, K, masks=masks, depth_unit=depth_unit,
                                                       image_size=image_size, return_errors=return_errors, up=up,
                                                       **crop_options)

    def track(self, source, **kwargs):
        """Stream poses over a frame source; see ``equipose.runtime.tracking.track`` for the options. Yields ``TrackRecord``."""
        from equipose.runtime.tracking import track
        return track(self, source, **kwargs)
