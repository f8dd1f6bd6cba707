"""Two samplers' figures on the same targets, each target answered on several draws: is
the candidate worse beyond what the draws explain?

The evaluation's component figures are ratios over units: count right, splits and merges
per target (one unit a target), recall over the counted exact components (C_t units on
target t). Each sampler answers every target on S draws (other sampling seeds); its value
on target t is the mean over the draws of the figure's sum there (right: 0 or 1; splits;
merges; exact components found). The candidate's gain on target t is d_t, its value less
the incumbent's (negated where less is better), and the figure's gain is
D = sum_t d_t / W over the W units. Both answer the same independent targets, so D's
standard error is sqrt(T / (T - 1) * sum_t (d_t - mean d)^2) / W (a paired test over the
T targets), and a figure is worse when D < -Z_REFUSE times it: the same sampler on other
draws, D ~ N(0, se), is refused on a figure one time in a hundred.

A mean over 200 targets cannot see one target lost for good (a sampler that misses one of
24 exact components on one target, every time). So a figure is also worse where a unit
is lost: right on every draw of the incumbent and wrong on every draw of the candidate
(count right: the target's count; splits, merges: none on the target; recall: the exact
component found). The same sampler loses a unit it gets right with probability p so with
chance p^S (1 - p)^S, at most 4^-S (1/256 at S = 4), and one it always or never gets right
never.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from service.pipeline.arrays import BoolArray, FloatArray, IntArray

Z_REFUSE = 2.326  # the standard normal's one-sided 1 % point


class Counts(NamedTuple):
    """One sampler's figure on T targets of S draws, as the paired test reads it."""

    sums: FloatArray  # (T, S) the figure's sum on each target and draw
    units: FloatArray  # (T,) the figure's units on each target
    good: BoolArray  # (U, S) whether each unit is right on each draw
    unit_target: IntArray  # (U,) the target of each unit


@dataclass(frozen=True)
class Paired:
    """One figure of a candidate against the incumbent over the same targets and draws."""

    gain: float  # D: the candidate's figure less the incumbent's, positive where better
    standard_error: float  # D's, over the targets
    lost_targets: list[int]  # the targets holding a unit lost on every draw

    @property
    def z(self) -> float:
        """D in standard errors; +-inf where every target's gain is the same nonzero one."""
        if self.standard_error > 0.0:
            return self.gain / self.standard_error
        return 0.0 if self.gain == 0.0 else math.copysign(math.inf, self.gain)

    @property
    def worse(self) -> bool:
        """Worse beyond the draws' spread, or a unit lost on every draw."""
        return self.z < -Z_REFUSE or bool(self.lost_targets)


def paired(candidate: Counts, incumbent: Counts, more_is_better: bool) -> Paired:
    """The paired gain of one figure, its standard error and the targets of lost units
    (the units and their targets are the incumbent's: both answer the same targets)."""
    gains = candidate.sums.mean(axis=1) - incumbent.sums.mean(axis=1)  # (T,)
    if not more_is_better:
        gains = -gains
    total = float(incumbent.units.sum())
    count = len(gains)
    spread = float(((gains - gains.mean()) ** 2).sum()) if count > 1 else 0.0
    standard_error = math.sqrt(count / (count - 1) * spread) / total if count > 1 else 0.0
    lost = incumbent.good.all(axis=1) & ~candidate.good.any(axis=1)  # (U,)
    return Paired(
        gain=float(gains.sum()) / total,
        standard_error=standard_error,
        lost_targets=sorted({int(t) for t in incumbent.unit_target[lost]}),
    )


def together(z_of_sets: list[float]) -> float:
    """Stouffer's z of one figure judged on k independent target sets: sum z_i / sqrt k,
    standard normal where the candidate is the incumbent on other draws, as each z_i is.
    Sets that each fall short of the refusal in the same direction refuse together (two
    at -1.8: -2.55 < -Z_REFUSE); one set's z is itself."""
    if not z_of_sets:
        raise ValueError("together needs the z of at least one target set")
    return sum(z_of_sets) / math.sqrt(len(z_of_sets))
