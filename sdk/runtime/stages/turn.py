"""Stage ``turn`` (metadata ``turn_classifier``): a small learned scorer of the view's canonical points decides
between the pose and its half turns (``equipose.runtime.turn_classifier``); under an up prior only the turn about up.
Result extra ``turn_margin``: the pose's lead in logits (below the file's ``ambiguous_margin``: ``ambiguous``).

Convention: model units, centred camera frame; rotation category → camera.
"""
from __future__ import annotations

from equipose.runtime.hypotheses import HALF_TURNS
from equipose.runtime.stage import ObjectState, Stage, register_stage
from equipose.runtime.turn_classifier import turn_scores

__all__ = ["TurnStage"]


@register_stage
class TurnStage(Stage):
    name = "turn"
    metadata_key = "turn_classifier"
    after = "flip"

    def __init__(self, turn: dict):
        self.turn = turn

    @classmethod
    def build(cls, spec, options, context):
        tc = spec.get(cls.metadata_key)
        return None if tc is None else cls(tc)

    def describe(self) -> dict:
        return {"axes": list(self.turn["axes"]), "margin": self.turn["margin"]}

    def run(self, state: ObjectState) -> None:
        axes = [a for a in self.turn["axes"] if state.up is None or a == "z"]  # the up prior holds x and y
        if not axes:
            return
        s = turn_scores(self.turn["weights"], state.points, state.rotation, state.translation, axes)   # [1 + A]
        k = int(s[1:].argmax())
        if s[1 + k] - s[0] > self.turn["margin"]:
            state.set_pose(state.rotation @ HALF_TURNS[axes[k]])
            s = s[[1 + k] + [j for j in range(len(s)) if j != 1 + k]]          # the turn is the pose now
        lead = float(s[0] - s[1:].max()) if len(s) > 1 else float("inf")
        state.extras["turn_margin"] = lead
        if lead < self.turn["ambiguous_margin"]:
            state.ambiguous = True
