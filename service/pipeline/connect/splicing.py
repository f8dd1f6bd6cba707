"""Stage 5 for r = 1: join by short walks on the fibre what the trace left apart.

Next to a singular value a curve can pass where continuation cannot follow it: on Panda
pose targets whose fibre comes near the elbow's stretched configuration (q4 near -0.47,
sigma_min(J) 4e-4 to 2e-3) the bordered corrector overshoots along J's second nearly
null direction at every step the trace can take, and both fronts stop a few hundredths
of a radian short of each other, on an arc that is almost straight. The curve is then
returned as two pieces, a split. A piece's end that is not on a joint limit is such a
stop (the trace cuts curves only at the limits).

Two open ends at most `reach_rad` apart are joined when the projected local planner
(local_planner.py) walks from one to the other on the fibre, inside the limits, without
a hop or a detour and without crossing a coaxial set where the fibre does not reach it:
the same evidence the roadmap accepts for an edge. Nearest pairs go first and each end is
joined once. The walk's points, thinned to the path spacing and put on the fibre by
Newton, fill the gap; if one of them cannot be made exact, the pieces stay apart. A
failed walk leaves both ends open as before: a split that stays visible (the answer is
near-singular), never a merge made to hide it.

The same walk attaches a sample that lies on no traced path (near the stretched elbow a
path's chord can miss its bending curve by more than the on-curve distance) to the path
it leads to, rather than leaving it to a roadmap of its own.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.local_planner import PlannerSettings, walk_on_fibre
from service.pipeline.correction import error_norms
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import project
from service.pipeline.joint_space import JointLimits
from service.pipeline.space import FibreSpace
from service.pipeline.types import ComponentPath, Correction

# An end lies on a limit when a limited joint is within this of it (the trace refines its
# cut ends onto the limit exactly).
ON_LIMIT_RAD = 1e-9
POLISH_ITERATIONS = 8  # Newton steps (undamped: exact near a singular value) per gap point
POLISH_ERROR = 5e-11  # |e| a gap point is taken to, like the trace's path points


@dataclass(frozen=True)
class SpliceSettings:
    reach_rad: float  # open ends at most this far apart are candidates
    planner: PlannerSettings  # the walk that must join them
    spacing_rad: float  # largest step of the spliced path (every added point valid)


@dataclass(frozen=True)
class _Points:
    """Exact points in order with their errors: a gap's filling or a piece's path."""

    q_rad: FloatArray  # (g, n)
    position_error_m: FloatArray  # (g,)
    orientation_error_rad: FloatArray  # (g,)

    def reversed(self) -> _Points:
        backwards = slice(None, None, -1)
        return _Points(
            self.q_rad[backwards],
            self.position_error_m[backwards],
            self.orientation_error_rad[backwards],
        )


@dataclass(frozen=True)
class _End:
    path: int  # which path
    last: bool  # its last point (else its first)


def open_ends(paths: Sequence[ComponentPath], limits: JointLimits) -> list[_End]:
    """The ends of the open paths that are not on a joint limit: where a trace stopped."""
    lower_rad, upper_rad, limited = limits.lower_rad, limits.upper_rad, ~limits.periodic
    ends = [
        _End(index, last)
        for index, path in enumerate(paths)
        if not path.closed and len(path.q_rad)
        for last in (False, True)
    ]
    if not ends:
        return []
    q = np.array([paths[e.path].q_rad[-1 if e.last else 0] for e in ends])  # (E, n)
    near = (np.abs(q - lower_rad) <= ON_LIMIT_RAD) | (np.abs(q - upper_rad) <= ON_LIMIT_RAD)
    # (E,) some limited joint on a limit
    touching: BoolArray = np.asarray(np.logical_and(limited, near).any(axis=1), dtype=bool)
    return [end for end, on in zip(ends, touching.tolist(), strict=True) if not on]


def splice_paths(
    space: FibreSpace,
    paths: list[ComponentPath],
    settings: SpliceSettings,
    deadline: Deadline = NO_DEADLINE,
) -> list[ComponentPath]:
    """The paths with every pair of open ends that the fibre joins spliced into one."""
    ends = open_ends(paths, space.limits)
    if len(ends) < 2:
        return paths
    q_end = np.array([_point(paths, e) for e in ends])  # (U, n)
    distance = space.limits.distance(q_end[:, None], q_end[None])  # (U, U)
    a, b = np.nonzero(np.triu(distance <= settings.reach_rad, k=1))
    # A path's own two ends close a loop only round a path longer than the gap's detour
    # (a piece of one point, a seed whose fronts never moved, has both ends in one place).
    path_of = np.array([e.path for e in ends])
    arc = np.array([paths[e.path].arc_length_rad for e in ends])
    keep = (path_of[a] != path_of[b]) | (arc[a] > settings.planner.lambda_ * settings.reach_rad)
    a, b = a[keep], b[keep]
    length = distance[a, b]
    if not len(a):
        return paths
    walks = walk_on_fibre(space, q_end[a], q_end[b], settings.planner, deadline=deadline)
    joins: dict[int, tuple[int, _Points]] = {}  # end -> (the end it joins, points between)
    for p in np.flatnonzero(walks.reached)[np.argsort(length[walks.reached], kind="stable")]:
        i, j = int(a[p]), int(b[p])
        if i in joins or j in joins:
            continue
        gap = _gap_points(space, q_end[i], q_end[j], walks.points_rad[p], settings)
        if gap is None:
            continue
        joins[i], joins[j] = (j, gap), (i, gap.reversed())
    if not joins:
        return paths
    return _chains(paths, ends, joins, space.limits)


def _point(paths: Sequence[ComponentPath], end: _End) -> FloatArray:
    return paths[end.path].q_rad[-1 if end.last else 0]


def _gap_points(
    space: FibreSpace,
    q_a: FloatArray,  # (n,)
    q_b: FloatArray,  # (n,)
    walked: FloatArray,  # (k, n) the walk's points from a toward b (unwrapped from a)
    settings: SpliceSettings,
) -> _Points | None:  # None: a point could not be made valid
    """Points of the walk, thinned so that no step of a -> points -> b exceeds the
    spacing, each taken onto the fibre by undamped Newton and checked valid
    (`FibreSpace.accept`: within the tolerance, inside the limits)."""
    fibre, limits = space.fibre, space.limits
    goal = q_a + limits.difference(q_b, q_a)  # b as the walk reached it
    chain = np.concatenate([q_a[None], walked, goal[None]])  # (k + 2, n), unwrapped
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(chain, axis=0), axis=1))])
    count = int(np.ceil(arc[-1] / (0.9 * settings.spacing_rad))) - 1  # inner points needed
    if count <= 0:
        return _Points(chain[:0], np.zeros(0), np.zeros(0))
    picks = np.unique(np.searchsorted(arc, arc[-1] * np.arange(1, count + 1) / (count + 1)))
    picks = picks[(picks > 0) & (picks < len(chain) - 1)]
    polished = project(
        replace(fibre, damping=0.0), chain[picks], POLISH_ITERATIONS, until=POLISH_ERROR
    )
    position, orientation = error_norms(polished.error, fibre.task)
    q = np.asarray(limits.wrap(polished.q_rad))
    exact = space.accept(Correction(q, position, orientation, polished.jacobian)).accepted
    before = np.concatenate([q_a[None], polished.q_rad])
    steps = limits.distance(before, np.concatenate([polished.q_rad, q_b[None]]))
    if not exact.all() or steps.max() > settings.spacing_rad:
        return None
    return _Points(q, position, orientation)


def _chains(
    paths: list[ComponentPath],
    ends: list[_End],
    joins: dict[int, tuple[int, _Points]],
    limits: JointLimits,
) -> list[ComponentPath]:
    """Each run of paths joined end to end as one path (closed when it comes back round);
    paths not spliced are returned as they were."""
    end_of = {(e.path, e.last): k for k, e in enumerate(ends)}
    used = np.zeros(len(paths), dtype=bool)
    spliced: list[ComponentPath] = []
    for start in _chain_starts(paths, ends, joins):
        if used[start]:
            continue
        # Enter `start` at an end with no join (else anywhere: the chain is a loop).
        first = end_of.get((start, False))
        unjoined_last = end_of.get((start, True)) not in joins
        entered_last = first is not None and first in joins and unjoined_last
        parts: list[tuple[ComponentPath, bool]] = []  # (path, walked backwards)
        gaps: list[_Points] = []
        path, backwards, closed = start, entered_last, False
        while True:
            used[path] = True
            parts.append((paths[path], backwards))
            leaving = end_of.get((path, not backwards))  # the end this path is left by
            if leaving is None or leaving not in joins:
                break
            other, gap = joins[leaving]
            nxt = ends[other]
            if used[nxt.path]:
                closed = nxt.path == start
                if closed:
                    gaps.append(gap)
                break
            gaps.append(gap)
            path, backwards = nxt.path, nxt.last
        if len(parts) == 1 and not closed:
            spliced.append(paths[start])
            continue
        spliced.append(_joined(parts, gaps, closed, limits))
    return spliced


def _chain_starts(
    paths: list[ComponentPath], ends: list[_End], joins: dict[int, tuple[int, _Points]]
) -> list[int]:
    """Paths in an order that starts every open chain at one of its ends: paths with an
    unjoined end first, then the rest (loops of spliced pieces)."""
    joined_ends: dict[int, int] = {}
    for k in joins:
        joined_ends[ends[k].path] = joined_ends.get(ends[k].path, 0) + 1
    open_first = [p for p in range(len(paths)) if joined_ends.get(p, 0) < 2]
    return open_first + [p for p in range(len(paths)) if joined_ends.get(p, 0) == 2]


def _joined(
    parts: list[tuple[ComponentPath, bool]], gaps: list[_Points], closed: bool, limits: JointLimits
) -> ComponentPath:
    """Pieces (each forwards or backwards) with the gap points between them, as one path
    (a loop ends with the gap that closes it)."""
    blocks: list[_Points] = []
    for index, (path, backwards) in enumerate(parts):
        piece = _Points(path.q_rad, path.position_error_m, path.orientation_error_rad)
        blocks.append(piece.reversed() if backwards else piece)
        if index < len(gaps):
            blocks.append(gaps[index])
    q = np.concatenate([b.q_rad for b in blocks])
    steps = limits.distance(q[1:], q[:-1])
    arc = float(steps.sum()) + (float(limits.distance(q[-1], q[0])) if closed else 0.0)
    return ComponentPath(
        q_rad=q,
        position_error_m=np.concatenate([b.position_error_m for b in blocks]),
        orientation_error_rad=np.concatenate([b.orientation_error_rad for b in blocks]),
        closed=closed,
        arc_length_rad=arc,
    )


def attach_by_walk(
    space: FibreSpace,
    q_rad: FloatArray,  # (K, n) valid samples
    paths: Sequence[ComponentPath],
    settings: SpliceSettings,
    deadline: Deadline = NO_DEADLINE,
) -> IntArray:  # (K,) the path each sample's walk reached, -1 for none
    """Each sample joins the path whose nearest point (within `reach_rad`) the local
    planner walks to from it."""
    owner = np.full(len(q_rad), -1)
    if not len(q_rad) or not paths:
        return owner
    points = np.concatenate([p.q_rad for p in paths])  # (P, n)
    which = np.concatenate([np.full(len(p.q_rad), i) for i, p in enumerate(paths)])  # (P,)
    box = space.limits.box(np.concatenate([points, q_rad]), margin_rad=1.0)
    distance, nearest = box.tree(points).query(box.points(q_rad))  # (K,), (K,)
    near = np.flatnonzero(distance <= settings.reach_rad)
    if not len(near):
        return owner
    walks = walk_on_fibre(
        space, q_rad[near], points[nearest[near]], settings.planner, deadline=deadline, record=False
    )
    owner[near[walks.reached]] = which[nearest[near[walks.reached]]]
    return owner
