"""Stage ``turn`` (metadata ``turn_classifier``): a small learned scorer of the view's canonical points decides
between the pose and its half turns (``equipose.runtime.turn_classifier``); under an up prior only the turn about up.
Result extras ``turn_margin``: the pose's lead in logits (below the file's ``ambiguous_margin``: ``ambiguous``), and
``flip_axis``: the category axis of the half turn of the reported pose that scored next best (``R @ HALF_TURNS[a]``,
``PoseResult.flip_rotation``).
Option ``points``: view points scored (evenly spaced along the model input).

Convention: model units, centred camera frame; rotation category → camera.
"""
from __future__ import annotations

from equipose.runtime.hypotheses import HALF_TURNS
from equipose.runtime.stage import ObjectState, Stage, register_stage
from equipose.core.errors import ConfigError
from equipose.runtime.turn_classifier import TURN_POINTS, TurnScorer, turned_sets

__all__ = ["TurnStage", "relative_turn"]


def relative_turn(a: str | None, b: str | None) -> str:
    """The axis of the half turn that takes the pose turned about ``a`` to the pose turned about ``b`` (None: not
    turned; ``a`` ≠ ``b``): the half turns about x, y and z commute, and two different ones make the third."""
    if a is None or b is None:
        return a or b
    return ({"x", "y", "z"} - {a, b}).pop()


@register_stage
class TurnStage(Stage):
    name = "turn"
    metadata_key = "turn_classifier"
    after = "flip"
    options = {"points": TURN_POINTS}

    def __init__(self, turn: dict, points: int = TURN_POINTS, threads: int = 1):
        self.turn, self.points = turn, int(points)
        self.scorer = TurnScorer(turn["weights"], threads)                      # the scorer's onnxruntime graph

    @classmethod
    def build(cls, spec, options, context):
        tc = spec.get(cls.metadata_key)
        n = options["points"]
        if isinstance(n, bool) or not isinstance(n, int) or n < 16:
            raise ConfigError(f"turn points must be an int ≥ 16, got {n!r}")
        return None if tc is None else cls(tc, n, int(context.get("threads") or 1))

    def describe(self) -> dict:
        return {"axes": list(self.turn["axes"]), "margin": self.turn["margin"], "points": self.points}

    def run(self, state: ObjectState) -> None:
        axes = [a for a in self.turn["axes"] if state.up is None or a == "z"]  # the up prior holds x and y
        if not axes:
            return
        s = self.scorer(turned_sets(state.points, state.rotation, state.translation, axes, self.points))  # [1 + A]
        turns = [None] + axes                                                   # each set's turn of the pose
        k = int(s[1:].argmax())
        chosen = 1 + k if s[1 + k] - s[0] > self.turn["margin"] else 0
        if chosen:
            state.set_pose(state.rotation @ HALF_TURNS[axes[k]])               # the turn is the pose now
        rival = max((j for j in range(len(s)) if j != chosen), key=lambda j: s[j])
        state.extras["turn_margin"] = float(s[chosen] - s[rival])
        state.extras["flip_axis"] = relative_turn(turns[chosen], turns[rival])
        if state.extras["turn_margin"] < self.turn["ambiguous_margin"]:
            state.ambiguous = True
