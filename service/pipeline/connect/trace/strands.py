"""Phase 3: the fronts chained through their seeds and meetings into ordered curves, and
how close two strands of the traced fibre come (where the structure is ambiguous)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.trace.points import Curve, Evaluated, curve, torus_difference
from service.pipeline.joint_space import JointLimits, joint_difference

# Two traced points are on different strands of one curve when they lie more than this
# many meeting distances apart along it (nearer, they are neighbours on one strand).
STRAND_ARC_FACTOR = 4.0

STRAND_GROUP = 3  # consecutive path points per point of closest_strands_rad's tree


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
    is traced as the wrong curves: the structure there is ambiguous. Candidate pairs come
    from a KD-tree on the limited joints as they are and the periodic ones embedded on
    circles (cos q, sin q), whose chord is never longer than their angle, so no pair
    within the distance is missed.

    The tree holds one point in STRAND_GROUP along each curve, its group's middle one:
    two points within `within_rad` have group points within `within_rad` + 2 delta (delta
    the longest arc from a point to its group's), so those group pairs, less the ones
    too near along one curve for any of their points to be two strands, give every
    candidate, and each is then measured point by point. Most pairs within the distance
    are neighbours on one strand; the coarser tree skips them (3 ms to 1 ms for the 1700
    path points of an iiwa pose target).
    """
    curves = [(q, closed) for q, closed in curves if len(q)]
    if not curves:
        return np.inf
    periodic = limits.periodic
    points = np.concatenate([q for q, _ in curves])  # (P, n)
    # Every step at once (across two curves' boundary too, left out below), each curve's
    # arc the running sum of its own steps.
    steps = np.linalg.norm(joint_difference(points[1:], points[:-1], periodic), axis=1)
    arc, length = [], []
    start = 0
    for q, loop in curves:
        arc.append(np.concatenate([[0.0], np.cumsum(steps[start : start + len(q) - 1])]))
        closing = np.linalg.norm(joint_difference(q[0], q[-1], periodic)) if loop else 0.0
        length.append(arc[-1][-1] + float(closing))
        start += len(q)
    curve = np.repeat(np.arange(len(curves)), [len(q) for q, _ in curves])  # (P,)
    s = np.concatenate(arc)  # (P,) arc position along its curve
    total = np.asarray(length)[curve]  # (P,)
    closed = np.array([closed for _, closed in curves])[curve]

    def apart(a: IntArray, b: IntArray) -> FloatArray:  # arc between points of one curve
        d = np.abs(s[a] - s[b])
        return np.where(closed[a], np.minimum(d, total[a] - d), d)

    # Groups of STRAND_GROUP consecutive points of a curve: members (G, STRAND_GROUP),
    # -1 past a curve's end, and each group's middle member, its point in the tree.
    index = np.concatenate([np.arange(len(q)) for q, _ in curves])  # (P,) within its curve
    first = index % STRAND_GROUP == 0  # (P,) a group starts here
    starts = np.flatnonzero(first)  # (G,)
    group = np.cumsum(first) - 1  # (P,)
    size = np.bincount(group)  # (G,) 1 to STRAND_GROUP
    members = starts[:, None] + np.arange(STRAND_GROUP)  # (G, STRAND_GROUP)
    members[np.arange(STRAND_GROUP) >= size[:, None]] = -1
    middle = starts + np.minimum(1, size - 1)  # (G,)
    delta = float(np.abs(s - s[middle[group]]).max())
    embedded = np.concatenate(  # (P, n + periodic joints)
        [points[:, ~periodic], np.cos(points[:, periodic]), np.sin(points[:, periodic])], axis=1
    )
    strand_arc = STRAND_ARC_FACTOR * within_rad
    if delta >= within_rad:  # steps too long for groups to help: every point in the tree
        pairs = cKDTree(embedded).query_pairs(r=within_rad, output_type="ndarray")  # (K, 2)
        a, b = pairs[:, 0], pairs[:, 1]
    else:
        pairs = cKDTree(embedded[middle]).query_pairs(
            r=within_rad + 2.0 * delta, output_type="ndarray"
        )  # (K, 2) groups
        ga, gb = middle[pairs[:, 0]], middle[pairs[:, 1]]
        # No point of either group can be a strand of the other's: one curve, too near.
        same = (curve[ga] == curve[gb]) & (apart(ga, gb) <= strand_arc - 2.0 * delta)
        pairs = pairs[~same]
        a = np.repeat(members[pairs[:, 0]], STRAND_GROUP, axis=1).ravel()  # (9K,)
        b = np.tile(members[pairs[:, 1]], STRAND_GROUP).ravel()
        a, b = a[(a >= 0) & (b >= 0)], b[(a >= 0) & (b >= 0)]
    if not len(a):
        return np.inf
    distance = np.linalg.norm(joint_difference(points[a], points[b], periodic), axis=1)
    strands = (curve[a] != curve[b]) | (apart(a, b) > strand_arc)
    close = strands & (distance <= within_rad)
    return float(distance[close].min()) if close.any() else np.inf


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
