"""Stage ``copies``: the network runs on K rotated copies of each object; their best hypotheses vote for a consensus.

The copies' input is built before inference (``input_batch``, ``equipose.runtime.copies``); ``unpack`` takes an
object's K rows of outputs back to the input's frame (hypotheses of copy 0, the copies' mean canonical shape), and
``run`` computes the consensus of the copies' best hypotheses (``consensus_pose``). Options: ``count`` K ("auto":
the file's ``refine_calibration`` copies when its ICP re-scoring runs, else 1 = off).

Convention: model units, centred camera frame; copy k sees ``Q_k x``.
"""
from __future__ import annotations

import numpy as np

from equipose.runtime.copies import consensus_pose, copy_batch, copy_rotations, undo_copies
from equipose.runtime.stage import ObjectState, Stage, register_stage

__all__ = ["CopiesStage"]


@register_stage
class CopiesStage(Stage):
    name = "copies"
    options = {"count": "auto"}

    def __init__(self, count: int):
        self.count = int(count)
        self.rotations = copy_rotations(self.count)                             # [K, 3, 3], copy 0 the identity

    @classmethod
    def build(cls, spec, options, context):
        count = options["count"]
        if isinstance(count, str) and count == "auto":
            rcal, rescore = spec.refine_calibration, context["options"].get("rescore", {})
            k = "auto" if rescore is False else rescore.get("k", "auto")
            rescoring = rcal is not None and rescore is not False and (k == "auto" or bool(k))
            count = rcal["copies"] if rescoring else 1
        stage = cls(count)                                                      # validates count
        return stage if stage.count > 1 else None

    def describe(self) -> dict:
        return {"count": self.count}

    def input_batch(self, preps) -> np.ndarray:
        """[B·K, N, 3] float32 network input: object b's copy k (its own sample, turned by Q_k) at row b·K + k."""
        return copy_batch(preps, self.rotations)

    def unpack(self, outputs: dict, b: int, prep, symmetry: str) -> ObjectState:
        """Object ``b``'s K rows → its state: copy 0's hypotheses, the mean canonical shape, each copy's best pose."""
        K = self.count
        rows = slice(b * K, (b + 1) * K)
        Rk, tk = undo_copies(outputs["hypothesis_rotations"][rows], outputs["hypothesis_translations"][rows],
                             self.rotations)                                    # [K, 60, 3, 3], [K, 60, 3]
        sk = np.asarray(outputs["hypothesis_scores"][rows], np.float64)        # [K, 60]
        canon = np.asarray(outputs["canonical_shape"][rows], np.float64).mean(0)  # [M, 3] mean over the copies
        first = sk.argmin(1)                                                    # [K] each copy's best
        best = (Rk[np.arange(K), first], tk[np.arange(K), first])               # [K, 3, 3], [K, 3]
        return ObjectState(prep=prep, R=Rk[0].copy(), t=tk[0].copy(), scores=sk[0].copy(), canonical=canon,
                           template=canon, symmetry=symmetry, copy_poses=best)

    def run(self, state: ObjectState) -> None:
        R_c, t_c, support = consensus_pose(*state.copy_poses, state.symmetry)
        state.consensus = (R_c, t_c, support, None)                            # score: set by re-scoring
        state.extras["agreement"] = float(support.mean())
