"""Is every configuration the service called free free by coal on the URDF's own geometry?

Checked: every configuration an answer returns (each component's members and path
points) and, from the recording check (recorder.py), the configurations its collision
check called free on the way: the accepted samples, the r > 1 roadmap's walk steps and
local-planner checks. The recorded set can be large on a 4-D fibre; at most
`RECORDED_PER_TARGET` of them, drawn at random with the target's seed, are checked, and
the report says how many. A violation is a configuration coal does not find free by the
margin (`CoalModel.free`); its coal clearance (distance, <= 0 touching) is then measured,
and the least one reported.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from service.pipeline.arrays import FloatArray
from service.pipeline.collision.scene import Obstacle
from training.evaluate.scenes.coal_model import CoalModel

RECORDED_PER_TARGET = 10000
VIOLATIONS_KEPT = 3  # configurations listed per target for a replay


@dataclass(frozen=True)
class Exactness:
    """Coal's verdict on one set of configurations."""

    checked: int
    violations: int
    worst_clearance_m: float | None  # least coal clearance among the violations
    violating_rad: list[list[float]]  # the first VIOLATIONS_KEPT of them

    @classmethod
    def of(
        cls, coal: CoalModel, q_rad: FloatArray, obstacles: Sequence[Obstacle], margin_m: float
    ) -> Exactness:
        free = coal.free(q_rad, obstacles, margin_m)
        bad = q_rad[~free]
        worst = float(coal.clearance_m(bad, obstacles).min()) if len(bad) else None
        return cls(len(q_rad), len(bad), worst, bad[:VIOLATIONS_KEPT].tolist())


def recorded_sample(recorded: FloatArray, seed: int) -> FloatArray:
    """All recorded configurations, or RECORDED_PER_TARGET of them drawn at random."""
    if len(recorded) <= RECORDED_PER_TARGET:
        return recorded
    rows = np.random.default_rng(seed).choice(len(recorded), RECORDED_PER_TARGET, replace=False)
    return recorded[np.sort(rows)]
