"""Phase 3: the fronts chained through their seeds and meetings into ordered curves, and
how close two strands of the traced fibre come (where the structure is ambiguous)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.trace.points import Curve, Evaluated, curve, torus_difference
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
    fronts: list[IntArray],  # per front, its points' rows in travel order
    partner: IntArray,  # (F,)
) -> list[Curve]:
    """Order every curve: seed, its + front, the partner front backwards to its seed, ..."""
    overlap = overlaps(evaluated.q_rad, fronts, partner)
    visited = np.zeros(num_seeds, dtype=bool)
    loops = []
    for first in range(num_seeds):
        if visited[first]:
            continue
        visited[first] = True
        seed = np.array([first])
        forward, closed = follow(fronts, partner, overlap, 2 * first, visited, first)
        if closed:
            loops.append(curve(evaluated, np.concatenate([seed, *forward]), closed=True))
            continue
        backward, _ = follow(fronts, partner, overlap, 2 * first + 1, visited, first)
        parts = [p[::-1] for p in backward[::-1]] + [seed] + forward
        loops.append(curve(evaluated, np.concatenate(parts), closed=False))
    return loops


def overlaps(q_rad: FloatArray, fronts: list[IntArray], partner: IntArray) -> BoolArray:
    """(F,) whether each front's last point lies past its partner's (fronts that met just
    after passing overlap by under a step): the partner's last point is behind it, against
    its last step. Chaining drops that point from the front it follows forward."""
    ends = [
        (f, rows[-2], rows[-1], fronts[other][-1])
        for f, (rows, other) in enumerate(zip(fronts, partner.tolist(), strict=True))
        if other >= 0 and len(rows) >= 2 and len(fronts[other])
    ]
    overlap = np.zeros(len(fronts), dtype=bool)
    if ends:
        front, before, last, theirs = (np.asarray(column) for column in zip(*ends, strict=True))
        travel = torus_difference(q_rad[last], q_rad[before])  # (E, n)
        behind = torus_difference(q_rad[theirs], q_rad[last])
        overlap[front] = np.einsum("en,en->e", behind, travel) < 0
    return overlap


def follow(
    fronts: list[IntArray], partner: IntArray, overlap: BoolArray, front: int,
    visited: BoolArray, stop_seed: int,
) -> tuple[list[IntArray], bool]:  # fmt: skip
    """Rows along the curve from a seed through `front` and on; closed if back at stop_seed."""
    parts: list[IntArray] = []
    while True:
        other = int(partner[front])
        if other < 0:
            parts.append(fronts[front])
            return parts, False
        parts.append(fronts[front][:-1] if overlap[front] else fronts[front])
        # The partner front ran from its seed to the meeting: walk it backwards to its seed.
        parts.append(fronts[other][::-1])
        seed = other // 2
        if seed == stop_seed:
            return parts, True
        if visited[seed]:  # a second chain met this one: stop rather than loop
            return parts, False
        visited[seed] = True
        parts.append(np.array([seed]))
        front = other ^ 1  # the seed's other front carries on in the same direction
