"""Stage 5 for r = 1: trace every curve of the fibre that a corrected sample lies on, whole.

The fibre of a regular target of a 1-D redundant arm is a union of closed curves on the
joint torus (every revolute joint is a circle to the kinematics; the limits come after).
Seeds are spread over the samples that reach the target (inside the limits or not);
from each, two fronts walk the curve in opposite directions by predictor-corrector
continuation: predict h along the unit tangent (the null vector of J), correct with
Newton on [J; t^T] dq = [e; 0]. All fronts advance in lockstep, one batched kinematics
call per corrector iteration. A front stops when it meets a front coming the other way
on the same curve (ends closer than the meeting distance, travelling head-on, the chord
between them along the tangent), so neighbouring seeds share the work and each curve
closes in about (largest gap between its seeds) / 2h steps. Chaining the fronts through
their seeds and meetings orders every curve; curves are then cut by the joint limits
(each end refined onto the limit with the limited joint held there) and densified to
the path spacing by Hermite interpolation and projection, every path point evaluated.

A front that cannot go on (the corrector fails, a step jumps, the step budget runs out)
leaves its curve open there; such a trace, and a fibre whose Jacobian comes near rank
deficiency, make the result `near_singular`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import Fibre, project, smallest_singular_value, unit_tangent
from service.pipeline.joint_space import TWO_PI, JointBox, wrap_to_pi


@dataclass(frozen=True)
class TraceSettings:
    step_rad: float  # h, the continuation step
    max_steps: int  # per front; a curve longer than fronts x steps x h stays open
    seed_spacing_rad: float  # seeds are at least this far apart (torus metric)
    path_spacing_rad: float  # largest gap between consecutive path points
    corrector_iterations: int = 1  # per continuation step (each costs one evaluation)
    path_iterations: int = 1  # Newton steps that put each path point on the fibre ...
    path_error: float = 1e-9  # ... and more for the points whose |e| is still above this,
    path_extra_iterations: int = 8  # up to this many


@dataclass(frozen=True)
class TracedPiece:
    """One component of the fibre within the limits, as an ordered path."""

    path_rad: FloatArray  # (P, n) in order along the curve, joints inside their limits
    error: FloatArray  # (P, m) task error at each path point
    closed: bool  # the path is a whole loop (its last point joins its first)


@dataclass(frozen=True)
class Trace:
    pieces: list[TracedPiece]
    complete: bool  # every front met another: every curve traced closed
    min_singular_value: float  # over the traced points (inf when nothing was traced)


@dataclass
class _Front:
    seed: int
    points: list[FloatArray] = field(default_factory=list)  # unwrapped, in travel order
    partner: int | None = None  # the front it met, end to end


def trace_fibre(
    fibre: Fibre,
    q_on_fibre_rad: FloatArray,  # (M, n) samples within tolerance, inside the limits or not
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
    settings: TraceSettings,
    deadline: Deadline = NO_DEADLINE,
) -> Trace:
    """Every curve through `q_on_fibre_rad`, cut by the limits, as ordered dense paths."""
    if len(q_on_fibre_rad) == 0:
        return Trace(pieces=[], complete=True, min_singular_value=np.inf)
    seeds = spread_seeds(q_on_fibre_rad, settings.seed_spacing_rad)  # (S, n)
    start = project(fibre, seeds, iterations=0)
    tangent0 = unit_tangent(start.jacobian)  # (S, n)
    ok = np.all(np.isfinite(tangent0), axis=1)
    seeds, tangent0 = start.q_rad[ok], tangent0[ok]
    sigma = [smallest_singular_value(start.jacobian)]
    loops, complete, traced_sigma = _walk(fibre, seeds, tangent0, settings, deadline)
    sigma.append(traced_sigma)
    loops = _refine_near_limits(fibre, loops, lower_rad, upper_rad, periodic, settings)
    pieces = []
    for loop, closed in loops:
        pieces.extend(_cut_by_limits(loop, closed, lower_rad, upper_rad, periodic))
    dense = _densify(fibre, pieces, lower_rad, upper_rad, periodic, settings)
    finite_sigma = np.concatenate([s[np.isfinite(s)] for s in sigma])
    return Trace(
        pieces=dense,
        complete=complete,
        min_singular_value=float(finite_sigma.min()) if len(finite_sigma) else np.inf,
    )


def spread_seeds(q_rad: FloatArray, spacing_rad: float, batch: int = 32) -> FloatArray:
    """A subset (S, n) of q_rad (M, n), greedily at least `spacing_rad` apart on the torus:
    in order, each point not within the spacing of one already chosen is chosen.

    The choice goes `batch` points at a time: the next points not yet covered choose among
    themselves (a small table of which are within the spacing of which), then every point
    within the spacing of a new seed is covered. No KD-tree, a few passes in all.
    """
    within = _Spacing(q_rad, spacing_rad)
    remaining = np.arange(len(q_rad))  # (R,) not within the spacing of a chosen seed, in order
    chosen = []
    while len(remaining):
        head = remaining[:batch]  # (K,)
        near = within(head, head)  # (K, K)
        free = np.ones(len(head), dtype=bool)
        picked = []
        for k in range(len(head)):
            if free[k]:
                picked.append(k)
                free &= ~near[k]
        chosen.append(head[picked])
        remaining = remaining[~within(remaining, chosen[-1]).any(axis=1)]
    return q_rad[np.concatenate(chosen)]


class _Spacing:
    """Which pairs of configurations are within a distance r on the joint torus.

    The chord between two points' circle embeddings (cos q, sin q), one matrix product for
    a whole table, is never longer than their torus distance d, and when it is at most r
    it is at least ratio x d (each joint's 2 sin(x / 2) >= ratio x over the x it then
    allows): only the pairs between the two bounds need d itself.
    """

    def __init__(self, q_rad: FloatArray, spacing_rad: float) -> None:
        self.q_rad = q_rad  # (M, n)
        self.circle = np.concatenate([np.cos(q_rad), np.sin(q_rad)], axis=1)  # (M, 2n)
        self.r2 = spacing_rad**2
        half = min(spacing_rad / 2.0, 1.0)
        self.sure2 = (half / np.arcsin(half)) ** 2 * self.r2 - 1e-9  # chord^2 below: within

    def __call__(self, rows_a: IntArray, rows_b: IntArray) -> BoolArray:  # (A,), (B,) -> (A, B)
        chord2 = 2.0 * self.q_rad.shape[1] - 2.0 * (self.circle[rows_a] @ self.circle[rows_b].T)
        near = chord2 < self.sure2
        a, b = np.nonzero(~near & (chord2 <= self.r2 + 1e-9))
        if len(a):
            offset = _torus_difference(self.q_rad[rows_a[a]], self.q_rad[rows_b[b]])
            near[a, b] = np.einsum("kn,kn->k", offset, offset) <= self.r2
        return near


def _torus_tree(q_rad: FloatArray) -> tuple[cKDTree, FloatArray]:
    """A KD-tree over q_rad (N, n) on the joint torus (every joint a circle, as the
    kinematics sees it) and the points it holds."""
    box = JointBox.covering(q_rad, np.ones(q_rad.shape[1], dtype=bool), margin_rad=0.0)
    return box.tree(q_rad), box.points(q_rad)


def _torus_difference(a: FloatArray, b: FloatArray) -> FloatArray:
    return wrap_to_pi(a - b)


def _unwrap(points: FloatArray) -> FloatArray:
    """Points (P, n) of a curve on the torus made continuous: every step the short way."""
    if len(points) < 2:
        return points
    steps = _torus_difference(points[1:], points[:-1])
    return np.concatenate([points[:1], points[0] + np.cumsum(steps, axis=0)])


def _walk(
    fibre: Fibre,
    seeds: FloatArray,  # (S, n) on the fibre
    tangent0: FloatArray,  # (S, n)
    settings: TraceSettings,
    deadline: Deadline,
) -> tuple[list[tuple[FloatArray, bool]], bool, FloatArray]:
    """Fronts in lockstep from every seed both ways; the curves as (points (P, n), closed).

    Each front has its own step: a step that fails (the corrector does not converge, pulls
    the prediction by more than a quarter step, which is how a step lands on a nearby
    curve, or the tangent turns sharply) is retried at half the length, down to 1/16 of
    h, and a good step lets the next one grow back by 1.5x: sharp bends near a singular
    value are walked, not jumped.
    """
    num_seeds, _n = seeds.shape
    h = settings.step_rad
    fronts = [_Front(seed=i // 2) for i in range(2 * num_seeds)]
    q = np.repeat(seeds, 2, axis=0)  # (F, n) front ends; front 2i goes along +t, 2i+1 along -t
    tangent = np.repeat(tangent0, 2, axis=0) * np.tile([1.0, -1.0], num_seeds)[:, None]
    step_rad = np.full(len(fronts), h)  # (F,)
    alive = np.ones(len(fronts), dtype=bool)
    jacobians: list[FloatArray] = []  # (A, m, n) per step: sigma_min once at the end
    for _ in range(settings.max_steps):
        if not alive.any():
            break
        deadline.check("connect")
        index = np.flatnonzero(alive)
        h_i = step_rad[index]
        predicted = q[index] + h_i[:, None] * tangent[index]  # (A, n)
        corrected = project(fibre, predicted, settings.corrector_iterations, tangent=tangent[index])
        step = np.linalg.norm(corrected.q_rad - q[index], axis=1)
        new_tangent = unit_tangent(corrected.jacobian, previous=tangent[index])
        turn = np.einsum("an,an->a", new_tangent, tangent[index])
        pulled = np.linalg.norm(corrected.q_rad - predicted, axis=1)
        moved = (
            (corrected.error_norm < 1e-2 * h_i / h)  # converged
            & (pulled < 0.25 * h_i)  # the corrector stayed near the prediction: same branch
            & (step < 2.0 * h_i)  # no jump
            & (turn > 0.5)  # the tangent turned by under 60 degrees
        )
        jacobians.append(corrected.jacobian[moved])
        retry = index[~moved]
        step_rad[retry] *= 0.5
        alive[retry[step_rad[retry] < h / 16]] = False  # gave up: its curve stays open
        previous = q.copy()
        index, corrected_q, new_tangent = index[moved], corrected.q_rad[moved], new_tangent[moved]
        q[index], tangent[index] = corrected_q, new_tangent
        step_rad[index] = np.minimum(h, 1.5 * step_rad[index])
        for front, point in zip(index.tolist(), corrected_q, strict=True):
            fronts[front].points.append(point)
        _meet(q, previous, tangent, step_rad, alive, fronts)
    loops = _chain(seeds, fronts)
    all_sigma = smallest_singular_value(np.concatenate(jacobians)) if jacobians else np.zeros(0)
    # A front that gave up but was met by another leaves its curve closed all the same.
    return loops, all(closed for _, closed in loops), all_sigma


def _meet(
    q: FloatArray,  # (F, n) front ends
    previous: FloatArray,  # (F, n) the ends one step before
    tangent: FloatArray,  # (F, n) directions of travel
    step_rad: FloatArray,  # (F,) each front's current step
    alive: BoolArray,  # (F,)
    fronts: list[_Front],
) -> None:
    """Stop the pairs of fronts that meet head-on on one curve (nearest pairs first).

    Two fronts meet when their ends are within 1.1 x the larger of their steps (fronts
    closing by the sum of their steps come that close at some step, possibly just after
    passing; the overlap is trimmed when the curve is chained), they travel in opposite
    directions, the chord between them runs along the curve, and they came closer in
    this step (so the two fronts leaving one seed never meet at their start).
    """
    reach = 1.1 * step_rad.max()
    pairs = _torus_tree(q)[0].query_pairs(reach, output_type="ndarray")
    if len(pairs) == 0:
        return
    a, b = pairs[:, 0], pairs[:, 1]
    chord = _torus_difference(q[b], q[a])  # (P, n) from a's end to b's end
    length = np.linalg.norm(chord, axis=1)
    before = np.linalg.norm(_torus_difference(previous[b], previous[a]), axis=1)
    near = length <= 1.1 * np.maximum(step_rad[a], step_rad[b])
    head_on = np.einsum("pn,pn->p", tangent[a], tangent[b]) < -0.5
    along = np.abs(np.einsum("pn,pn->p", chord, tangent[a])) >= 0.7 * length
    closer = length < before
    partnerless = np.array([fronts[i].partner is None and fronts[j].partner is None
                            for i, j in zip(a, b, strict=True)])  # fmt: skip
    ok = near & head_on & along & closer & partnerless & (alive[a] | alive[b])
    for p in np.flatnonzero(ok)[np.argsort(length[ok])]:
        i, j = int(a[p]), int(b[p])
        if fronts[i].partner is None and fronts[j].partner is None:
            fronts[i].partner, fronts[j].partner = j, i
            alive[i] = alive[j] = False


def _chain(seeds: FloatArray, fronts: list[_Front]) -> list[tuple[FloatArray, bool]]:
    """Order every curve: seed, its + front, the partner front backwards to its seed, ..."""
    visited = np.zeros(len(seeds), dtype=bool)
    loops = []
    for first in range(len(seeds)):
        if visited[first]:
            continue
        visited[first] = True
        forward, closed = _follow(seeds, fronts, 2 * first, visited, stop_seed=first)
        if closed:
            loops.append((_unwrap(np.concatenate([seeds[first][None], *forward])), True))
            continue
        backward, _ = _follow(seeds, fronts, 2 * first + 1, visited, stop_seed=first)
        parts = [p[::-1] for p in backward[::-1]] + [seeds[first][None]] + forward
        loops.append((_unwrap(np.concatenate(parts)), False))
    return loops


def _follow(
    seeds: FloatArray, fronts: list[_Front], front: int, visited: BoolArray, stop_seed: int
) -> tuple[list[FloatArray], bool]:
    """Points along the curve from a seed through `front` and on; closed if back at stop_seed."""
    n = seeds.shape[1]
    parts: list[FloatArray] = []
    while True:
        mine = np.asarray(fronts[front].points).reshape(-1, n)
        partner = fronts[front].partner
        if partner is None:
            parts.append(mine)
            return parts, False
        # The partner front ran from its seed to the meeting: walk it backwards to its seed.
        theirs = np.asarray(fronts[partner].points).reshape(-1, n)[::-1]
        if len(mine) >= 2 and len(theirs):
            # Fronts that met just after passing overlap by under a step: drop the overlap.
            travel = _torus_difference(mine[-1], mine[-2])
            if np.dot(_torus_difference(theirs[0], mine[-1]), travel) < 0:
                mine = mine[:-1]
        parts.append(mine)
        parts.append(theirs)
        seed = fronts[partner].seed
        if seed == stop_seed:
            return parts, True
        if visited[seed]:  # a second chain met this one: stop rather than loop
            return parts, False
        visited[seed] = True
        parts.append(seeds[seed][None])
        front = partner ^ 1  # the seed's other front carries on in the same direction


def _window_low(lower_rad: FloatArray, upper_rad: FloatArray, periodic: BoolArray) -> FloatArray:
    """Lower end (n,) of the 2 pi window each joint angle is read in: the limits inside it."""
    centre = np.where(periodic, 0.0, 0.5 * (lower_rad + upper_rad))
    return centre - np.pi


def to_window(q_rad: FloatArray, window_low: FloatArray) -> FloatArray:
    """Angles (..., n) mapped into [window_low, window_low + 2 pi)."""
    return window_low + np.mod(q_rad - window_low, TWO_PI)


def _refine_near_limits(
    fibre: Fibre,
    loops: list[tuple[FloatArray, bool]],
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    periodic: BoolArray,
    settings: TraceSettings,
    rounds: int = 3,
    pieces: int = 4,
) -> list[tuple[FloatArray, bool]]:
    """Curves with points added where a step may pass through the limits unseen.

    A component shorter than a step can lie between two traced points that are both
    outside the limits. Where the chord of a step, widened by how far a curve bends in
    a step, meets the limit box, the step is split into `pieces` projected points; a
    few rounds find components down to about h / pieces**rounds long.
    """
    low = _window_low(lower_rad, upper_rad, periodic)
    loops = list(loops)
    for _ in range(rounds):
        candidates: list[tuple[int, int]] = []  # (loop, index of the step's first point)
        for k, (loop, closed) in enumerate(loops):
            ends = np.concatenate([loop, loop[:1]]) if closed else loop
            a = to_window(ends[:-1], low)  # (S, n)
            b = a + _torus_difference(ends[1:], ends[:-1])
            inside_a = np.all(periodic | ((a >= lower_rad) & (a <= upper_rad)), axis=1)
            inside_b = np.all(periodic | ((b >= lower_rad) & (b <= upper_rad)), axis=1)
            # A curve bends off its chord by ~kappa L^2 / 8: a margin of L / 4 per step.
            margin = 0.25 * np.linalg.norm(b - a, axis=1, keepdims=True)  # (S, 1)
            meets = _chord_meets_box(a, b, lower_rad - margin, upper_rad + margin, periodic)
            candidates.extend(
                (k, first) for first in np.flatnonzero(meets & ~inside_a & ~inside_b).tolist()
            )
        if not candidates:
            break
        starts, steps = [], []
        for k, first in candidates:
            loop = loops[k][0]
            starts.append(loop[first])
            steps.append(_torus_difference(loop[(first + 1) % len(loop)], loop[first]))
        start, delta = np.asarray(starts), np.asarray(steps)  # (C, n)
        fraction = np.arange(1, pieces) / pieces  # (pieces - 1,)
        guess = start[:, None, :] + fraction[None, :, None] * delta[:, None, :]  # (C, p-1, n)
        direction = np.repeat(delta / np.linalg.norm(delta, axis=1, keepdims=True), pieces - 1, 0)
        projected = project(fibre, guess.reshape(-1, start.shape[1]), 2, tangent=direction)
        new = projected.q_rad.reshape(guess.shape)
        converged = projected.error_norm < 1e-6
        ok = np.all(converged.reshape(len(candidates), pieces - 1), axis=1)
        inserts: dict[int, list[tuple[int, FloatArray]]] = {}
        for c, (k, first) in enumerate(candidates):
            if ok[c]:
                inserts.setdefault(k, []).append((first, new[c]))
        for k, added in inserts.items():
            loop, closed = loops[k]
            parts: list[FloatArray] = []
            previous = 0
            for first, points in sorted(added, key=lambda item: item[0]):
                parts.extend([loop[previous : first + 1], points])
                previous = first + 1
            parts.append(loop[previous:])
            loops[k] = (_unwrap(np.concatenate(parts)), closed)
    return loops


def _chord_meets_box(
    a: FloatArray, b: FloatArray, lower: FloatArray, upper: FloatArray, periodic: BoolArray
) -> BoolArray:  # (S,)
    """Whether each segment a -> b (S, n) passes through the box (slab test, limited joints)."""
    d = b - a
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lower - a) / d
        t2 = (upper - a) / d
    entry = np.where(
        d == 0, np.where((a >= lower) & (a <= upper), -np.inf, np.inf), np.minimum(t1, t2)
    )
    leave = np.where(
        d == 0, np.where((a >= lower) & (a <= upper), np.inf, -np.inf), np.maximum(t1, t2)
    )
    entry = np.where(periodic, -np.inf, entry).max(axis=1)
    leave = np.where(periodic, np.inf, leave).min(axis=1)
    return (entry <= leave) & (leave >= 0.0) & (entry <= 1.0)


@dataclass(frozen=True)
class _Run:
    points: FloatArray  # (P, n) unwrapped, in order
    closed: bool
    start_exit: FloatArray | None  # (n,) the outside point before the run (open runs)
    end_exit: FloatArray | None  # (n,) the outside point after the run


def _cut_by_limits(
    loop: FloatArray, closed: bool, lower_rad: FloatArray, upper_rad: FloatArray,
    periodic: BoolArray,
) -> list[_Run]:  # fmt: skip
    """The runs of consecutive points of a curve (P, n) that lie inside the limits."""
    low = _window_low(lower_rad, upper_rad, periodic)
    inside = np.all(periodic | ((to_window(loop, low) >= lower_rad) &
                                (to_window(loop, low) <= upper_rad)), axis=1)  # fmt: skip
    if inside.all():
        return [_Run(loop, closed, None, None)]
    if not inside.any():
        return []
    if closed:  # rotate so that the loop starts outside: runs never wrap
        shift = int(np.flatnonzero(~inside)[0])
        loop, inside = _unwrap(np.roll(loop, -shift, axis=0)), np.roll(inside, -shift)
    edges = np.diff(np.concatenate([[0], inside.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    runs = []
    for begin, end in zip(starts.tolist(), stops.tolist(), strict=True):
        before = loop[begin - 1] if begin > 0 else (loop[-1] if closed else None)
        after = loop[end] if end < len(loop) else (loop[0] if closed else None)
        runs.append(_Run(loop[begin:end], False, before, after))
    return runs


def _densify(
    fibre: Fibre,
    runs: list[_Run],
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    periodic: BoolArray,
    settings: TraceSettings,
) -> list[TracedPiece]:
    """Each run with its ends refined onto the limits, at the path spacing, all projected."""
    if not runs:
        return []
    n = runs[0].points.shape[1]
    low = _window_low(lower_rad, upper_rad, periodic)
    ends = _limit_points(fibre, runs, lower_rad, upper_rad, periodic, low)
    segments: list[FloatArray] = []
    fixed_rows: list[BoolArray] = []
    fixed_errors: list[FloatArray] = []
    for r, run in enumerate(runs):
        first, last = ends[2 * r], ends[2 * r + 1]
        parts = [run.points]
        if first is not None:
            parts.insert(0, first.q_rad[None])
            fixed_errors.append(first.error)
        if last is not None:
            parts.append(last.q_rad[None])
        points = np.concatenate(parts)
        if run.closed:  # back to the first point, the short way round
            points = np.concatenate(
                [points, points[-1:] + _torus_difference(points[:1], points[-1:])]
            )
        dense = _interpolate(points, 0.9 * settings.path_spacing_rad)
        if run.closed:
            dense = dense[:-1]
        fixed = np.zeros(len(dense), dtype=bool)
        fixed[0], fixed[-1] = first is not None, last is not None
        if last is not None:
            fixed_errors.append(last.error)
        segments.append(dense)
        fixed_rows.append(fixed)
    every = np.concatenate(segments)  # (P, n)
    fixed = np.concatenate(fixed_rows)  # (P,)
    free = ~fixed
    # The refined limit points are already exact; projecting them again would push them
    # across their limit, so only the others are projected (along the chord normal plane).
    chord_tangent = _chord_tangents(segments)  # (P, n)
    projected = project(fibre, every[free], settings.path_iterations, tangent=chord_tangent[free])
    q = every.copy()
    error = np.zeros((len(every), projected.error.shape[1]))
    q[free], error[free] = projected.q_rad, projected.error
    again = np.flatnonzero(free)[~(projected.error_norm <= settings.path_error)]
    for _ in range(settings.path_extra_iterations):  # near a singular value: more Newton
        if not len(again):
            break
        refined = project(fibre, q[again], iterations=1, tangent=chord_tangent[again])
        q[again], error[again] = refined.q_rad, refined.error
        again = again[~(refined.error_norm <= settings.path_error)]
    # A point that Newton carried away from its place on the path is left out.
    strayed = np.linalg.norm(q - every, axis=1) > 0.5 * settings.path_spacing_rad
    if fixed.any():
        error[fixed] = np.asarray(fixed_errors)
    q = to_window(q, low)
    inside = np.all(periodic | ((q >= lower_rad) & (q <= upper_rad)), axis=1) & ~strayed
    q = np.where(periodic, wrap_to_pi(q), q)
    pieces = []
    offsets = np.cumsum([0] + [len(d) for d in segments])
    for r, run in enumerate(runs):
        rows = np.arange(offsets[r], offsets[r + 1])
        rows = rows[inside[rows]]  # a point the projection pushed past a limit is left out
        pieces.append(
            TracedPiece(
                path_rad=q[rows].reshape(-1, n),
                error=error[rows],
                closed=run.closed,
            )
        )
    return pieces


@dataclass(frozen=True)
class _LimitPoint:
    q_rad: FloatArray  # (n,) unwrapped like its run
    error: FloatArray  # (m,) task error there


def _limit_points(
    fibre: Fibre, runs: list[_Run], lower_rad: FloatArray, upper_rad: FloatArray,
    periodic: BoolArray, window_low: FloatArray,
) -> list[_LimitPoint | None]:  # fmt: skip
    """For each run, its start and end refined onto the joint limit its curve crosses there.

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
    found: list[_LimitPoint | None] = [None] * (2 * len(runs))
    if not inner:
        return found
    a, b = np.asarray(inner), np.asarray(outer)  # (E, n) unwrapped, consecutive on the curve
    b = a + _torus_difference(b, a)
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
    refined = project(fibre, guess, iterations=6, locked=locked)
    q = refined.q_rad
    q[rows, joint] = bound  # exactly on the limit (the locked joint did not move)
    inside = np.all(periodic | ((q >= lower_rad) & (q <= upper_rad)), axis=1)
    close = np.linalg.norm(q - a_w, axis=1) <= 2.0 * np.linalg.norm(b_w - a_w, axis=1)
    good = inside & close & (refined.error_norm < 1e-8)
    for e, key in enumerate(keys):
        if good[e]:
            # Back to the run's unwrapped coordinates: the same offset as its inner point.
            found[key] = _LimitPoint(q[e] + (a[e] - a_w[e]), refined.error[e])
    return found


def _interpolate(points: FloatArray, spacing_rad: float) -> FloatArray:
    """Points (P, n) with straight-line points inserted so that gaps are <= spacing_rad."""
    if len(points) < 2:
        return points
    gap = np.linalg.norm(np.diff(points, axis=0), axis=1)  # (P - 1,)
    pieces = np.maximum(np.ceil(gap / spacing_rad).astype(np.int64), 1)  # sub-steps per gap
    start = np.repeat(points[:-1], pieces, axis=0)
    delta = np.repeat(np.diff(points, axis=0) / pieces[:, None], pieces, axis=0)
    offset = np.arange(pieces.sum()) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    return np.concatenate([start + offset[:, None] * delta, points[-1:]])


def _chord_tangents(segments: list[FloatArray]) -> FloatArray:
    """A unit direction (P, n) along each path at each point (central chords)."""
    out = []
    for points in segments:
        if len(points) == 1:
            out.append(np.full_like(points, 1.0 / np.sqrt(points.shape[1])))
            continue
        ahead = np.concatenate([points[1:], points[-1:]])
        behind = np.concatenate([points[:1], points[:-1]])
        chord = ahead - behind
        out.append(chord / np.linalg.norm(chord, axis=1, keepdims=True))
    return np.concatenate(out)
