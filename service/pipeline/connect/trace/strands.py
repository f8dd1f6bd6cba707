"""Phase 3: the fronts chained through their seeds and meetings into ordered curves, and
how close two strands of the traced fibre come (where the structure is ambiguous)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.connect.trace.points import Curves, Evaluated
from service.pipeline.joint_space import JointLimits

# Two traced points are on different strands of one curve when they lie more than this
# many meeting distances apart along it (nearer, they are neighbours on one strand).
STRAND_ARC_FACTOR = 4.0


def closest_strands_rad(
    curves: Sequence[tuple[FloatArray, bool]],  # (P_c, n) ordered points, closed or not
    limits: JointLimits,
    within_rad: float,
) -> float:
    """The closest approach (joint metric) of two strands of the traced fibre: points of
    two different curves, or of one curve but more than STRAND_ARC_FACTOR x `within_rad`
    apart along it (the shorter way round a closed one); inf when none is within
    `within_rad`.

    Fronts meet within 1.1 h, so two strands closer than that are told apart only by the
    twins test of `meet`, and a fibre that runs as twins closer than the test resolves
    is traced as the wrong curves: the structure there is ambiguous. Compiled
    (`native.closest_strands`): a sweep over one embedded coordinate (a limited joint, or
    the cosine or sine of a periodic one, whose difference is never more than the joint
    metric's) pairs only points within `within_rad` in it, and skips at once the pairs that
    are neighbours on one strand, most of them (1.0 to 0.1 ms for the 1700 path points of
    an iiwa14 pose target, against a KD-tree's pairs).
    """
    curves = [(q, closed) for q, closed in curves if len(q)]
    if not curves:
        return np.inf
    points = np.concatenate([q for q, _ in curves])  # (P, n)
    first = np.cumsum([0] + [len(q) for q, _ in curves])  # (C + 1,)
    closed = np.array([loop for _, loop in curves])
    strand_arc = STRAND_ARC_FACTOR * within_rad
    return native.closest_strands(points, first, closed, limits.periodic, within_rad, strand_arc)


def chain(
    evaluated: Evaluated,
    num_seeds: int,  # the seeds are the first rows of `evaluated`
    by_front: IntArray,  # (T - S,) the front that reached each later row, in travel order
    partner: IntArray,  # (F,) the front each met, -1: none
) -> Curves:
    """Order every curve: seed, its + front, the partner front backwards to its seed, ...

    From each seed not yet on a curve: the seed, its + front, the partner front walked
    backwards to its seed, that seed's other front, and so on, until back at the first seed
    (a closed curve), at a front that met none, or at a seed another chain took (open: then
    the same from the seed's - front, in front of the seed). Fronts that met just after
    passing overlap by under a step: the point of the one followed forward that lies past
    its partner's last point is left out. Compiled (`native.chain_fronts`).
    """
    rows, first, closed = native.chain_fronts(evaluated.q_rad, num_seeds, by_front, partner)
    return Curves.of(evaluated, rows, first, closed)
