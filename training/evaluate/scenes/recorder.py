"""The service's answer with a record of every configuration its collision check called
free, so that the evaluation can check each of them with coal too.

`RecordingCheck` is the query's own `CollisionCheck` (same robot, scene, self check and
margin, so the same verdicts) that keeps the rows its verdicts (`judged`, which `free`
asks) called free: the accepted samples, every walk step of an r > 1 roadmap edge and
the local planner's checks, the members of the r = 1 free pieces. `recorded_answer`
runs the pipeline's own stages (`service.pipeline.run`: encode, then `answer`: sample,
correct, accept, in rounds where the model draws so, connect, summarise) in a space
built with that check, since `run` builds its check inside; the service's code is not
changed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from service.models.registry import ServedModel
from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.run import (
    Stopwatch,
    answer,
    collision_of,
    encode,
    run,
    space_of,
)
from service.pipeline.types import Query, SmmResult


@dataclass(frozen=True)
class RecordingCheck(CollisionCheck):
    """A CollisionCheck that records the configurations it calls free: the walks ask it
    step by step (their numpy loops, pinned to the compiled ones by the tests), where the
    compiled walks would decide in C unseen."""

    called_free: list[FloatArray] = field(default_factory=list, compare=False)
    compiled_walks: ClassVar[bool] = False

    @classmethod
    def like(cls, check: CollisionCheck) -> RecordingCheck:
        return cls(
            robot=check.robot, scene=check.scene, check_self=check.check_self,
            margin_m=check.margin_m,
        )  # fmt: skip

    def judged(self, q_rad: FloatArray) -> tuple[FloatArray, BoolArray]:
        """`free` asks this too: every verdict of the check passes here."""
        clearance, free = super().judged(q_rad)
        if self.active:  # with nothing checked, nothing was called free by a check
            self.called_free.append(np.array(q_rad[free], dtype=np.float64))
        return clearance, free

    def recorded(self, num_joints: int) -> FloatArray:  # (R, n), each distinct row once
        """Every configuration called free, each once."""
        if not self.called_free:
            return np.zeros((0, num_joints))
        return np.unique(np.concatenate(self.called_free), axis=0)


def recorded_answer(model: ServedModel, query: Query) -> tuple[SmmResult, RecordingCheck]:
    """The service's answer to `query`, stage by stage as `run` gives it, with the check
    that recorded what it called free."""
    target = encode(model, query)
    check = RecordingCheck.like(collision_of(model, query))
    space = space_of(model, target, query.tolerance, check)
    result = answer(model, query, target, Stopwatch(), space=space)
    return result, check


def same_answer(model: ServedModel, query: Query, result: SmmResult) -> bool:
    """Whether `run` gives the recorded answer: the same components, configurations and
    paths (the recording check changed nothing)."""
    served = run(model, query)
    if len(served.components) != len(result.components):
        return False
    for a, b in zip(served.components, result.components, strict=True):
        if not np.array_equal(a.configurations_rad, b.configurations_rad):
            return False
        if (a.path is None) != (b.path is None):
            return False
        if (
            a.path is not None
            and b.path is not None
            and not np.array_equal(a.path.q_rad, b.path.q_rad)
        ):
            return False
    return True
