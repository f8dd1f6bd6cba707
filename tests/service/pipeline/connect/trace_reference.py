"""The trace's phases after the walk as numpy and Python loops, kept as the reference the
compiled ones are pinned to (tests/service/pipeline/connect/test_densify.py): the fronts
chained into curves (each a `Curve` of its own), the curves cut by the limits into runs,
each run's ends refined onto the limits, and the runs densified to the path spacing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.trace.cut import along, hermite, to_window, window_low
from service.pipeline.connect.trace.points import (
    Curves,
    Evaluated,
    TracedPiece,
    TraceSettings,
    torus_difference,
)
from service.pipeline.fibre import Fibre, Projection, evaluate, newton, project, unit_tangent
from service.pipeline.joint_space import JointLimits


@dataclass(frozen=True)
class Curve:
    """A traced curve: rows of the evaluated points in order along it."""

    rows: IntArray  # (P,)
    points: FloatArray  # (P, n) those points made continuous (unwrapped)
    closed: bool  # the last point joins the first


def curve(evaluated: Evaluated, rows: IntArray, closed: bool) -> Curve:
    return Curve(rows, unwrap(evaluated.q_rad[rows]), closed)


def unwrap(points: FloatArray) -> FloatArray:
    """Points (P, n) of a curve on the torus made continuous: every step the short way."""
    if len(points) < 2:
        return points
    steps = torus_difference(points[1:], points[:-1])
    return np.concatenate([points[:1], points[0] + np.cumsum(steps, axis=0)])


def curve_list(curves: Curves) -> list[Curve]:
    """The flat curves as one `Curve` each."""
    return [
        Curve(curves.rows[a:b], curves.points[a:b], bool(closed))
        for a, b, closed in zip(curves.first[:-1], curves.first[1:], curves.closed, strict=True)
    ]


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


def refine_near_limits(
    fibre: Fibre,
    evaluated: Evaluated,
    loops: list[Curve],
    limits: JointLimits,
    settings: TraceSettings,
    rounds: int = 3,
    pieces: int = 4,
) -> tuple[Evaluated, list[Curve]]:
    """Curves with points added where a step may pass through the limits unseen.

    A component shorter than a step can lie between two traced points that are both
    outside the limits. Where the chord of a step, widened by how far a curve bends in
    a step, meets the limit box, the step is split into `pieces` projected points (from
    the Hermite curve through its ends); a few rounds, each looking again only at the
    pieces of the steps the last one split, find components down to about
    h / pieces**rounds long. The evaluated points come back with the added ones.
    """
    low = window_low(limits)
    lower_rad, upper_rad, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    steps = Steps.of(evaluated, loops)
    added: list[Evaluated] = []
    added_loop: list[IntArray] = []
    added_key: list[FloatArray] = []  # place in the loop: its step's first point + fraction
    fraction = np.arange(1, pieces) / pieces  # (p - 1,)
    for _ in range(rounds):
        # Both ends outside, the chord through the box widened by a margin of L / 4 per
        # step (a curve bends off its chord by ~kappa L^2 / 8), by the slab test (compiled).
        steps = steps.take(
            native.steps_near_limits(steps.start, steps.delta, low, lower_rad, upper_rad, periodic)
        )
        if not len(steps.loop):
            break
        count = len(steps.loop)
        guess, direction = hermite(
            np.repeat(steps.start, pieces - 1, axis=0),
            np.repeat(steps.start_tangent, pieces - 1, axis=0),
            np.repeat(steps.start + steps.delta, pieces - 1, axis=0),
            np.repeat(steps.end_tangent, pieces - 1, axis=0),
            np.tile(fraction, count),
        )  # (C (p - 1), n)
        projected = project(fibre, guess, 2, tangent=direction, until=settings.path_error)
        ok = np.all((projected.error_norm < 1e-6).reshape(count, pieces - 1), axis=1)  # (C,)
        if not ok.any():
            break
        new_rows = len(evaluated) + np.arange((pieces - 1) * ok.sum()).reshape(-1, pieces - 1)
        keep = np.repeat(ok, pieces - 1)
        new = Evaluated.of(projected, unit_tangent(projected.jacobian, previous=direction))
        added.append(new.take(keep))
        evaluated = evaluated.extended(added[-1])
        steps = steps.take(ok)
        added_loop.append(np.repeat(steps.loop, pieces - 1))
        added_key.append((steps.key[:, None] + steps.span[:, None] * fraction).ravel())
        steps = steps.split(new_rows, evaluated)
    if not added:
        return evaluated, loops
    loop_of = np.concatenate(added_loop)
    key = np.concatenate(added_key)
    rows = len(evaluated) - len(loop_of) + np.arange(len(loop_of))  # the added rows, in order
    loops = list(loops)
    for k in np.unique(loop_of).tolist():
        mine = loop_of == k
        places = np.concatenate([np.arange(len(loops[k].rows)), key[mine]])
        merged = np.concatenate([loops[k].rows, rows[mine]])[np.argsort(places, kind="stable")]
        loops[k] = curve(evaluated, merged, loops[k].closed)
    return evaluated, loops


@dataclass(frozen=True)
class Steps:
    """Steps of traced curves between evaluated points (C of them), as the refinement
    looks at them: unwrapped start and chord, tangents along the chord at both ends."""

    loop: IntArray  # (C,) which curve
    key: FloatArray  # (C,) where the step starts in the curve: point index (+ fraction)
    span: FloatArray  # (C,) how much of the curve's step it is: 1, 1 / pieces, ...
    start: FloatArray  # (C, n) unwrapped like the curve
    delta: FloatArray  # (C, n) to the step's end, the short way on the torus
    start_tangent: FloatArray  # (C, n) unit, along delta
    end_tangent: FloatArray  # (C, n)

    @classmethod
    def of(cls, evaluated: Evaluated, loops: list[Curve]) -> Steps:
        """Every step of every curve (the closing step of a closed one included)."""
        n = evaluated.q_rad.shape[1]
        if not loops:
            none = np.zeros((0, n))
            return cls(np.zeros(0, np.int64), np.zeros(0), np.zeros(0), none, none, none, none)
        size = np.array([len(curve.rows) for curve in loops])  # (L,)
        first = np.cumsum(size) - size  # (L,) where each curve starts
        loop = np.repeat(np.arange(len(loops)), size)  # (P,)
        place = np.arange(len(loop)) - first[loop]  # (P,) index in its curve
        following = np.arange(len(loop)) + 1  # (P,) the point after, round a closed curve
        last = place == size[loop] - 1
        following[last] = first[loop[last]]
        step = ~last | np.array([curve.closed for curve in loops])[loop]
        rows = np.concatenate([curve.rows for curve in loops])
        row_a, row_b = rows[step], rows[following[step]]  # (C,) each step's ends
        delta = torus_difference(evaluated.q_rad[row_b], evaluated.q_rad[row_a])
        return cls(
            loop=loop[step],
            key=place[step].astype(np.float64),
            span=np.ones(len(delta)),
            start=np.concatenate([curve.points for curve in loops])[step],
            delta=delta,
            start_tangent=along(evaluated.tangent[row_a], delta),
            end_tangent=along(evaluated.tangent[row_b], delta),
        )

    def take(self, rows: BoolArray) -> Steps:
        return Steps(
            self.loop[rows], self.key[rows], self.span[rows], self.start[rows],
            self.delta[rows], self.start_tangent[rows], self.end_tangent[rows],
        )  # fmt: skip

    def split(self, new_rows: IntArray, evaluated: Evaluated) -> Steps:
        """Each step as its `pieces` steps through the new points (C, pieces - 1) inside it."""
        count, inner = new_rows.shape
        pieces = inner + 1
        q = evaluated.q_rad[new_rows]  # (C, p - 1, n)
        end = self.start + self.delta
        # The new points in the step's unwrapped coordinates: each moved little from its guess.
        q = self.start[:, None, :] + torus_difference(q, self.start[:, None, :])
        nodes = np.concatenate([self.start[:, None], q, end[:, None]], axis=1)  # (C, p + 1, n)
        tangents = np.concatenate(
            [self.start_tangent[:, None], evaluated.tangent[new_rows], self.end_tangent[:, None]],
            axis=1,
        )  # (C, p + 1, n)
        delta = np.diff(nodes, axis=1).reshape(-1, nodes.shape[2])  # (C p, n)
        span = np.repeat(self.span / pieces, pieces)
        return Steps(
            loop=np.repeat(self.loop, pieces),
            key=np.repeat(self.key, pieces) + span * np.tile(np.arange(pieces), count),
            span=span,
            start=nodes[:, :-1].reshape(-1, nodes.shape[2]),
            delta=delta,
            start_tangent=along(tangents[:, :-1].reshape(delta.shape), delta),
            end_tangent=along(tangents[:, 1:].reshape(delta.shape), delta),
        )


@dataclass(frozen=True)
class Run:
    rows: IntArray  # (P,) evaluated points in order
    points: FloatArray  # (P, n) those points unwrapped
    closed: bool
    start_exit: FloatArray | None  # (n,) the outside point before the run (open runs)
    end_exit: FloatArray | None  # (n,) the outside point after the run


def cut_by_limits(loops: list[Curve], limits: JointLimits) -> list[Run]:
    """The runs of consecutive points of each curve that lie inside the limits."""
    if not loops:
        return []
    window = to_window(np.concatenate([loop.points for loop in loops]), window_low(limits))
    inside_all = limits.contains(window)  # (P,)
    per_loop = np.split(inside_all, np.cumsum([len(loop.rows) for loop in loops])[:-1])
    runs = []
    for loop, inside in zip(loops, per_loop, strict=True):
        if inside.all():
            runs.append(Run(loop.rows, loop.points, loop.closed, None, None))
            continue
        if not inside.any():
            continue
        rows, points, closed = loop.rows, loop.points, loop.closed
        if closed:  # rotate so that the loop starts outside: runs never wrap
            shift = int(np.argmin(inside))
            turns = points[-1] + torus_difference(points[0], points[-1]) - points[0]  # (n,)
            rows = np.concatenate([rows[shift:], rows[:shift]])
            inside = np.concatenate([inside[shift:], inside[:shift]])
            points = np.concatenate([points[shift:], points[:shift] + turns])
        edges = np.diff(np.concatenate([[0], inside.astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        for begin, end in zip(starts.tolist(), stops.tolist(), strict=True):
            before = points[begin - 1] if begin > 0 else (points[-1] if closed else None)
            after = points[end] if end < len(points) else (points[0] if closed else None)
            runs.append(Run(rows[begin:end], points[begin:end], False, before, after))
    return runs


@dataclass(frozen=True)
class Nodes:
    """Every run's nodes in order (its traced points and its refined limit points), as
    rows of the evaluated points extended by the limit points."""

    q_rad: FloatArray  # (N, n) unwrapped along each run
    row: IntArray  # (N,) rows of `evaluated.extended(limits)`
    run: IntArray  # (N,) the run each node belongs to
    last: BoolArray  # (N,) the run's last node: no segment after it


@dataclass(frozen=True)
class Layout:
    """The dense path: each node, then the inner points of the segment to the next."""

    inner: IntArray  # (N,) inner points after each node
    offset: IntArray  # (N,) dense row of each node
    segment: IntArray  # (D,) the node each dense row follows
    between: IntArray  # (I,) dense rows that are inner points
    part: IntArray  # (D,) 0 for a node, k for the k-th inner point after it


def densify(
    fibre: Fibre,
    evaluated: Evaluated,
    runs: list[Run],
    limits: JointLimits,
    settings: TraceSettings,
) -> list[TracedPiece]:
    """Each run with its ends refined onto the limits, at the path spacing, all evaluated.

    A run's nodes are its traced points and its refined limit points. Between two nodes
    a chord of length L gets ceil(L / (0.9 spacing)) - 1 points on the cubic Hermite
    curve through the nodes' tangents, within O(L^4) of the fibre, and Newton puts each on
    it (orthogonally to the curve's direction), with more steps for the points whose |e|
    is still above path_error. A traced node needs no second evaluation: Newton goes on
    from what the trace measured there, and a node already within path_error stays as it
    is. The refined limit points are exact and are not moved (another step would push
    them across their limit).
    """
    if not runs:
        return []
    n = runs[0].points.shape[1]
    low = window_low(limits)
    found, found_window, limit_of = limit_points(fibre, runs, evaluated, limits, low, settings)
    nodes = evaluated.extended(found)  # a limit point's row: len(evaluated) + its index
    node = _nodes(runs, evaluated, found, limit_of)
    chord = np.diff(node.q_rad, axis=0)  # (N - 1, n)
    layout = _layout(node, chord, settings.path_spacing_rad)
    k = layout.segment[layout.between]
    guess, direction = hermite(
        node.q_rad[k],
        along(nodes.tangent[node.row[k]], chord[k]),
        node.q_rad[k + 1],
        along(nodes.tangent[node.row[k + 1]], chord[k]),
        layout.part[layout.between] / (layout.inner[k] + 1),
    )  # (I, n)
    # The closing node of a closed run repeats its first; a limit point is kept as it is.
    repeated = np.zeros(len(node.row), dtype=bool)
    repeated[np.flatnonzero(node.last)] = [run.closed for run in runs]
    limit_node = node.row >= len(evaluated)
    moving_node = np.flatnonzero(~repeated & ~limit_node)
    placed = np.empty((len(layout.segment), n))  # (D, n) where each point was put before Newton
    placed[layout.offset] = node.q_rad
    placed[layout.between] = guess
    known_rows = node.row[moving_node]
    known = Projection(node.q_rad[moving_node], nodes.error[known_rows], nodes.jacobian[known_rows])
    start = _stack(known, evaluate(fibre, guess)) if len(guess) else known
    tangent = np.concatenate([nodes.tangent[known_rows], direction])
    moved = newton(
        fibre, start, settings.path_iterations, tangent=tangent, until=settings.path_error
    )
    q = placed.copy()
    error = np.empty((len(layout.segment), nodes.error.shape[1]))
    error[layout.offset] = nodes.error[node.row]  # the limit points' (the others are set next)
    moved_rows = np.concatenate([layout.offset[moving_node], layout.between])
    q[moved_rows], error[moved_rows] = moved.q_rad, moved.error
    # Into the window, a limit point as refined (on its limit exactly, not through its
    # run's coordinates); left out: a point past a limit, one Newton carried away from its
    # place on the path, the closing repeat of a closed run.
    q, inside = native.settle_dense(
        q, placed, low, limits.lower_rad, limits.upper_rad, limits.periodic,
        stray_rad=0.5 * settings.path_spacing_rad,
        fixed_rows=layout.offset[limit_node],
        fixed_rad=found_window[node.row[limit_node] - len(evaluated)],
        excluded_rows=layout.offset[repeated],
    )  # fmt: skip
    bounds = np.searchsorted(node.run[layout.segment], np.arange(len(runs) + 1))
    pieces = []
    for r, run in enumerate(runs):
        rows = np.arange(bounds[r], bounds[r + 1])
        rows = rows[inside[rows]]  # a point the projection pushed past a limit is left out
        path = TracedPiece(path_rad=q[rows].reshape(-1, n), error=error[rows], closed=run.closed)
        pieces.append(path)
    return pieces


def _nodes(runs: list[Run], evaluated: Evaluated, found: Evaluated, limit_of: IntArray) -> Nodes:
    """Each run's nodes: its refined start, its traced points, its refined end, and for a
    closed run its first point again (the short way round)."""
    node_q: list[FloatArray] = []  # per run (N_r, n), unwrapped
    node_rows: list[IntArray] = []  # per run (N_r,) rows of `nodes`
    for r, run in enumerate(runs):
        first, last = limit_of[2 * r], limit_of[2 * r + 1]
        points, rows = run.points, run.rows
        if first >= 0:
            points = np.concatenate([found.q_rad[first][None], points])
            rows = np.concatenate([[len(evaluated) + first], rows])
        if last >= 0:
            points = np.concatenate([points, found.q_rad[last][None]])
            rows = np.concatenate([rows, [len(evaluated) + last]])
        if run.closed:  # back to the first point, the short way round
            closing = points[-1:] + torus_difference(points[:1], points[-1:])
            points, rows = np.concatenate([points, closing]), np.append(rows, rows[0])
        node_q.append(points)
        node_rows.append(rows)
    run_of = np.repeat(np.arange(len(runs)), [len(rows) for rows in node_rows])  # (N,)
    return Nodes(
        q_rad=np.concatenate(node_q),
        row=np.concatenate(node_rows),
        run=run_of,
        last=np.append(run_of[1:] != run_of[:-1], True),
    )


def _layout(node: Nodes, chord: FloatArray, spacing_rad: float) -> Layout:
    """How many inner points each segment gets (chord / (0.9 spacing), rounded up, less
    one; none after a run's last node) and where every point lies in the dense path."""
    inner = np.ceil(np.linalg.norm(chord, axis=1) / (0.9 * spacing_rad))
    inner = np.append(np.where(node.last[:-1], 0, np.maximum(inner, 1) - 1), 0).astype(np.int64)
    offset = np.cumsum(inner + 1) - (inner + 1)  # (N,) dense row of each node
    segment = np.repeat(np.arange(len(node.row)), inner + 1)  # (D,)
    part = np.arange(len(segment)) - offset[segment]  # (D,) 0 for the node itself
    return Layout(inner, offset, segment, np.flatnonzero(part > 0), part)


def _stack(*parts: Projection) -> Projection:
    return Projection(
        q_rad=np.concatenate([p.q_rad for p in parts]),
        error=np.concatenate([p.error for p in parts]),
        jacobian=np.concatenate([p.jacobian for p in parts]),
    )


def limit_points(
    fibre: Fibre,
    runs: list[Run],
    evaluated: Evaluated,
    limits: JointLimits,
    window_low: FloatArray,  # (n,)
    settings: TraceSettings,
) -> tuple[Evaluated, FloatArray, IntArray]:
    """Each run's start and end refined onto the joint limit its curve crosses there: the
    refined points (L,), unwrapped like their runs, the same (L, n) in window coordinates
    (the limited joint on its limit exactly), and for each run end (2 x runs, start then
    end) the index of its point, -1 for none.

    Between the last point inside and the first outside, the joint that leaves first is
    set on its limit and held there while Newton puts the rest back on the fibre. A
    refined point that lands outside another limit or off the fibre is dropped (the run
    then ends at its last traced point, within a step of the limit).
    """
    inner, outer, keys = [], [], []
    for r, run in enumerate(runs):
        if run.start_exit is not None:
            inner.append(run.points[0])
            outer.append(run.start_exit)
            keys.append(2 * r)
        if run.end_exit is not None:
            inner.append(run.points[-1])
            outer.append(run.end_exit)
            keys.append(2 * r + 1)
    lower_rad, upper_rad, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    found = np.full(2 * len(runs), -1)
    n, m = evaluated.q_rad.shape[1], evaluated.error.shape[1]
    if not inner:
        none = Evaluated(np.zeros((0, n)), np.zeros((0, m)), np.zeros((0, m, n)), np.zeros((0, n)))
        return none, np.zeros((0, n)), found
    a, b = np.asarray(inner), np.asarray(outer)  # (E, n) unwrapped, consecutive on the curve
    b = a + torus_difference(b, a)
    a_w = to_window(a, window_low)
    b_w = a_w + (b - a)  # the same step in window coordinates (may leave the window)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_low = np.where(b_w < lower_rad, (a_w - lower_rad) / (a_w - b_w), np.inf)
        t_high = np.where(b_w > upper_rad, (upper_rad - a_w) / (b_w - a_w), np.inf)
    t_cross = np.where(periodic, np.inf, np.minimum(t_low, t_high))  # (E, n)
    joint = np.argmin(t_cross, axis=1)  # (E,)
    rows = np.arange(len(a))
    t = np.clip(t_cross[rows, joint], 0.0, 1.0)
    guess = a_w + t[:, None] * (b_w - a_w)
    bound = np.where(t_low[rows, joint] <= t_high[rows, joint], lower_rad[joint], upper_rad[joint])
    guess[rows, joint] = bound
    locked = np.zeros_like(guess, dtype=bool)
    locked[rows, joint] = True
    refined = project(fibre, guess, iterations=6, locked=locked, until=settings.path_error)
    q = refined.q_rad
    q[rows, joint] = bound  # exactly on the limit (the locked joint did not move)
    inside = limits.contains(q)
    close = np.linalg.norm(q - a_w, axis=1) <= 2.0 * np.linalg.norm(b_w - a_w, axis=1)
    good = inside & close & (refined.error_norm < 1e-8)
    # Back to the runs' unwrapped coordinates: the same offset as each inner point.
    tangent = unit_tangent(refined.jacobian, previous=b - a)
    points = Evaluated(q + (a - a_w), refined.error, refined.jacobian, tangent).take(good)
    found[np.asarray(keys)[good]] = np.arange(good.sum())
    return points, q[good], found
