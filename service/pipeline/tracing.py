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
the path spacing: points on the cubic Hermite curve through the traced points and their
tangents, each put on the fibre by Newton and evaluated where it is returned. Every
traced point keeps what the kinematics measured there (error, Jacobian, tangent), so no
point is evaluated twice.

A front that cannot go on (the corrector fails, a step jumps, the step budget runs out)
leaves its curve open there (the connect stage splices such pieces where the fibre joins
them: splicing.py); such a trace, a fibre whose Jacobian comes near rank
deficiency, and two strands of the fibre closer than the fronts' meeting distance
(`closest_strands_rad`: the meeting test cannot always tell them apart; next to a
singular value the fibre can run as twin strands a few hundredths of a radian apart, or
far less, while sigma_min(J) stays moderate, as on the planar 3R within 1e-4 of
|x| = 1) make the result `near_singular`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import (
    Fibre,
    Projection,
    evaluate,
    min_singular_value,
    newton,
    project,
    smallest_singular_value,
    unit_tangent,
)
from service.pipeline.joint_space import TWO_PI, joint_difference, wrap_to_pi

# sigma_min(J) below which two meeting fronts may be on twin curves (the iiwa's elbow
# twins at q4 = +-0.015, 0.03 rad apart, have sigma_min ~ 0.006; on regular pose targets
# the fibre's least sigma_min is ~0.1).
TWIN_SIGMA = 0.05
TWIN_OFFSET = 0.05  # x h: the chord's offset from the mean tangent that marks twins
MEET_FACTOR = 1.1  # x h: fronts whose ends come this close may meet
# Two traced points are on different strands of one curve when they lie more than this
# many meeting distances apart along it (nearer, they are neighbours on one strand).
STRAND_ARC_FACTOR = 4.0
STRAND_GROUP = 3  # consecutive path points per point of closest_strands_rad's tree


@dataclass(frozen=True)
class TraceSettings:
    step_rad: float  # h, the continuation step
    max_steps: int  # per front; a curve longer than fronts x steps x h stays open
    seed_spacing_rad: float  # seeds are at least this far apart (torus metric)
    path_spacing_rad: float  # largest gap between consecutive path points
    corrector_iterations: int = 1  # per continuation step (each costs one evaluation)
    # Newton puts each path point within this |e| (well under any tolerance: a point
    # from a Hermite guess usually gets there in one step, and a second costs little) ...
    path_error: float = 5e-11
    path_iterations: int = 9  # ... in at most this many steps (each costs one evaluation)


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


@dataclass(frozen=True)
class _Evaluated:
    """Configurations the kinematics was evaluated at, with what it measured there.

    Every traced point is kept with its error, Jacobian and tangent, so that no later
    step evaluates it again: curves refer to these points by row.
    """

    q_rad: FloatArray  # (T, n) as evaluated (on the torus: any turn of each joint)
    error: FloatArray  # (T, m)
    jacobian: FloatArray  # (T, m, n)
    tangent: FloatArray  # (T, n) unit null vector of the Jacobian, either sign

    @classmethod
    def of(cls, projection: Projection, tangent: FloatArray) -> _Evaluated:
        return cls(projection.q_rad, projection.error, projection.jacobian, tangent)

    def __len__(self) -> int:
        return len(self.q_rad)

    def take(self, rows: IntArray | BoolArray) -> _Evaluated:
        return _Evaluated(
            self.q_rad[rows], self.error[rows], self.jacobian[rows], self.tangent[rows]
        )

    def extended(self, *others: _Evaluated) -> _Evaluated:
        parts = (self, *others)
        return _Evaluated(
            np.concatenate([p.q_rad for p in parts]),
            np.concatenate([p.error for p in parts]),
            np.concatenate([p.jacobian for p in parts]),
            np.concatenate([p.tangent for p in parts]),
        )


@dataclass(frozen=True)
class _Curve:
    """A traced curve: rows of the evaluated points in order along it."""

    rows: IntArray  # (P,)
    points: FloatArray  # (P, n) those points made continuous (unwrapped)
    closed: bool  # the last point joins the first


def _curve(evaluated: _Evaluated, rows: IntArray, closed: bool) -> _Curve:
    return _Curve(rows, _unwrap(evaluated.q_rad[rows]), closed)


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
    start = evaluate(fibre, spread_seeds(q_on_fibre_rad, settings.seed_spacing_rad))  # (S,)
    tangent0 = unit_tangent(start.jacobian)  # (S, n)
    seeds = _Evaluated.of(start, tangent0).take(np.all(np.isfinite(tangent0), axis=1))
    evaluated, loops, complete = _walk(fibre, seeds, settings, deadline)
    # sigma_min over the seeds and every point the fronts reached.
    sigma = min_singular_value(np.concatenate([start.jacobian, evaluated.jacobian[len(seeds) :]]))
    evaluated, loops = _refine_near_limits(
        fibre, evaluated, loops, lower_rad, upper_rad, periodic, settings
    )
    runs = _cut_by_limits(loops, lower_rad, upper_rad, periodic)
    dense = _densify(fibre, evaluated, runs, lower_rad, upper_rad, periodic, settings)
    return Trace(pieces=dense, complete=complete, min_singular_value=sigma)


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
    seeds: _Evaluated,  # (S,) on the fibre, with their tangents
    settings: TraceSettings,
    deadline: Deadline,
) -> tuple[_Evaluated, list[_Curve], bool]:
    """Fronts in lockstep from every seed both ways; every point they reached (the seeds
    first, then the fronts' points), the curves through them, and whether all closed.

    Each front has its own step: a step that fails (the corrector does not converge, pulls
    the prediction by more than a quarter step, which is how a step lands on a nearby
    curve, or the tangent turns sharply) is retried at half the length, down to 1/16 of
    h, and a good step lets the next one grow back by 1.5x: sharp bends near a singular
    value are walked, not jumped.
    """
    num_seeds = len(seeds)
    h = settings.step_rad
    num_fronts = 2 * num_seeds  # front 2i leaves seed i along +t, front 2i + 1 along -t
    q = np.repeat(seeds.q_rad, 2, axis=0)  # (F, n) front ends
    tangent = np.repeat(seeds.tangent, 2, axis=0) * np.tile([1.0, -1.0], num_seeds)[:, None]
    jacobian = np.repeat(seeds.jacobian, 2, axis=0)  # (F, m, n) at the front ends
    step_rad = np.full(num_fronts, h)  # (F,)
    alive = np.ones(num_fronts, dtype=bool)
    partner = np.full(num_fronts, -1)  # (F,) the front each met, end to end
    reached: list[_Evaluated] = []  # per step, the points the fronts moved to
    reached_by: list[IntArray] = []  # per step, which fronts moved
    for _ in range(settings.max_steps):
        if not alive.any():
            break
        deadline.check("connect")
        index = np.flatnonzero(alive)
        h_i, q_i, t_i = step_rad[index], q[index], tangent[index]  # (A,), (A, n), (A, n)
        predicted = q_i + h_i[:, None] * t_i
        corrected = project(fibre, predicted, settings.corrector_iterations, tangent=t_i)
        step = np.linalg.norm(corrected.q_rad - q_i, axis=1)
        new_tangent = unit_tangent(corrected.jacobian, previous=t_i)
        turn = np.einsum("an,an->a", new_tangent, t_i)
        pulled = np.linalg.norm(corrected.q_rad - predicted, axis=1)
        moved = (
            (corrected.error_norm < 1e-2 * h_i / h)  # converged
            & (pulled < 0.25 * h_i)  # the corrector stayed near the prediction: same branch
            & (step < 2.0 * h_i)  # no jump
            & (turn > 0.5)  # the tangent turned by under 60 degrees
        )
        retry = index[~moved]
        step_rad[retry] *= 0.5
        alive[retry[step_rad[retry] < h / 16]] = False  # gave up: its curve stays open
        previous = q.copy()
        index = index[moved]
        reached.append(_Evaluated.of(corrected, new_tangent).take(moved))
        reached_by.append(index)
        q[index], tangent[index] = reached[-1].q_rad, reached[-1].tangent
        jacobian[index] = reached[-1].jacobian
        step_rad[index] = np.minimum(h, 1.5 * step_rad[index])
        _meet(q, previous, tangent, jacobian, step_rad, h, alive, partner)
    evaluated = seeds.extended(*reached)
    # Each front's points in travel order, as rows of `evaluated` (after the seeds).
    by_front = np.concatenate([np.zeros(0, dtype=np.int64), *reached_by])  # (T - S,)
    order = np.argsort(by_front, kind="stable")
    bounds = np.searchsorted(by_front[order], np.arange(num_fronts + 1))
    fronts = [num_seeds + order[bounds[f] : bounds[f + 1]] for f in range(num_fronts)]
    loops = _chain(evaluated, num_seeds, fronts, partner)
    # A front that gave up but was met by another leaves its curve closed all the same.
    return evaluated, loops, all(loop.closed for loop in loops)


def _meet(
    q: FloatArray,  # (F, n) front ends
    previous: FloatArray,  # (F, n) the ends one step before
    tangent: FloatArray,  # (F, n) directions of travel
    jacobian: FloatArray,  # (F, m, n) at the front ends
    step_rad: FloatArray,  # (F,) each front's current step
    h: float,  # the full continuation step
    alive: BoolArray,  # (F,) updated: fronts that met stop
    partner: IntArray,  # (F,) updated: the front each met, -1 for none
) -> None:
    """Stop the pairs of fronts that meet head-on on one curve (nearest pairs first).

    Two fronts meet when their ends are within 1.1 x the larger of their steps (fronts
    closing by the sum of their steps come that close at some step, possibly just after
    passing; the overlap is trimmed when the curve is chained), they travel in opposite
    directions, the chord between them runs along the curve, and they came closer in
    this step (so the two fronts leaving one seed never meet at their start).
    """
    live = np.flatnonzero(alive)  # (A,) a front that met another is no longer alive
    if not len(live):
        return
    # Candidates by the chord between the points' circle embeddings (cos q, sin q), never
    # longer than the torus distance: one (A, 2n) x (2n, F) product, no KD-tree.
    circle = np.concatenate([np.cos(q), np.sin(q)], axis=1)  # (F, 2n)
    chordal2 = 2.0 * q.shape[1] - 2.0 * (circle[live] @ circle.T)  # (A, F)
    reach = MEET_FACTOR * step_rad.max()
    row, b = np.nonzero(chordal2 <= reach * reach + 1e-9)
    a = live[row]
    pair = (a != b) & (partner[b] < 0) & ((a < b) | ~alive[b])  # each pair once
    a, b = np.minimum(a[pair], b[pair]), np.maximum(a[pair], b[pair])
    if not len(a):
        return
    chord = _torus_difference(q[b], q[a])  # (P, n) from a's end to b's end
    length = np.linalg.norm(chord, axis=1)
    before = np.linalg.norm(_torus_difference(previous[b], previous[a]), axis=1)
    near = length <= MEET_FACTOR * np.maximum(step_rad[a], step_rad[b])
    head_on = np.einsum("pn,pn->p", tangent[a], tangent[b]) < -0.5
    along = np.abs(np.einsum("pn,pn->p", chord, tangent[a])) >= 0.7 * length
    closer = length < before
    # Near a singular value the curves can run in parallel pairs (twins) a few hundredths
    # of a radian apart, about as far apart as sigma_min(J) is small. There, where both
    # fronts walk at the full step (the curve bends gently), the chord of one arc is
    # parallel to the mean of its end tangents (exactly so on a circle; measured on the
    # iiwa pose, off by at most 0.002 rad at meetings on one curve): off it by more than
    # TWIN_OFFSET x h, the ends lie on two twins, which stay their gap apart (0.027 to
    # 0.066 rad on report targets 50, 70, 132). Elsewhere, and in sharp bends (a step was
    # halved), the looser test above decides.
    candidate = np.flatnonzero(near & head_on & along & closer)
    if len(candidate):
        pa, pb = a[candidate], b[candidate]
        mean = tangent[pa] - tangent[pb]  # (C, n), the fronts travel head-on
        mean /= np.maximum(np.linalg.norm(mean, axis=1, keepdims=True), 1e-300)
        c = chord[candidate]
        offset = np.linalg.norm(c - np.einsum("cn,cn->c", c, mean)[:, None] * mean, axis=1)
        # sigma_min (an SVD per row) only where the cheap tests leave a pair in doubt.
        doubt = (np.minimum(step_rad[pa], step_rad[pb]) >= h) & (offset > TWIN_OFFSET * h)
        if doubt.any():
            da, db = pa[doubt], pb[doubt]
            sigma = np.minimum(
                smallest_singular_value(jacobian[da]), smallest_singular_value(jacobian[db])
            )
            along[candidate[np.flatnonzero(doubt)[sigma < TWIN_SIGMA]]] = False
    ok = np.flatnonzero(near & head_on & along & closer)
    for p in ok[np.argsort(length[ok])].tolist():
        i, j = int(a[p]), int(b[p])
        if partner[i] < 0 and partner[j] < 0:
            partner[i], partner[j] = j, i
            alive[i] = alive[j] = False


def closest_strands_rad(
    curves: Sequence[tuple[FloatArray, bool]],  # (P_c, n) ordered points, closed or not
    periodic: BoolArray,  # (n,)
    within_rad: float,
) -> float:
    """The closest approach (joint metric) of two strands of the traced fibre: points of
    two different curves, or of one curve but more than STRAND_ARC_FACTOR x `within_rad`
    apart along it (the shorter way round a closed one); inf when none is within
    `within_rad`.

    Fronts meet within 1.1 h, so two strands closer than that are told apart only by the
    twins test of `_meet`, and a fibre that runs as twins closer than the test resolves
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
    arc, length = [], []
    for q, closed in curves:
        steps = np.linalg.norm(joint_difference(q[1:], q[:-1], periodic), axis=1)
        arc.append(np.concatenate([[0.0], np.cumsum(steps)]))
        closing = np.linalg.norm(joint_difference(q[0], q[-1], periodic)) if closed else 0.0
        length.append(arc[-1][-1] + float(closing))
    points = np.concatenate([q for q, _ in curves])  # (P, n)
    curve = np.concatenate([np.full(len(q), c) for c, (q, _) in enumerate(curves)])  # (P,)
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


def _chain(
    evaluated: _Evaluated,
    num_seeds: int,  # the seeds are the first rows of `evaluated`
    fronts: list[IntArray],  # per front, its points' rows in travel order
    partner: IntArray,  # (F,)
) -> list[_Curve]:
    """Order every curve: seed, its + front, the partner front backwards to its seed, ..."""
    overlap = _overlaps(evaluated.q_rad, fronts, partner)
    visited = np.zeros(num_seeds, dtype=bool)
    loops = []
    for first in range(num_seeds):
        if visited[first]:
            continue
        visited[first] = True
        seed = np.array([first])
        forward, closed = _follow(fronts, partner, overlap, 2 * first, visited, first)
        if closed:
            loops.append(_curve(evaluated, np.concatenate([seed, *forward]), closed=True))
            continue
        backward, _ = _follow(fronts, partner, overlap, 2 * first + 1, visited, first)
        parts = [p[::-1] for p in backward[::-1]] + [seed] + forward
        loops.append(_curve(evaluated, np.concatenate(parts), closed=False))
    return loops


def _overlaps(q_rad: FloatArray, fronts: list[IntArray], partner: IntArray) -> BoolArray:
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
        travel = _torus_difference(q_rad[last], q_rad[before])  # (E, n)
        behind = _torus_difference(q_rad[theirs], q_rad[last])
        overlap[front] = np.einsum("en,en->e", behind, travel) < 0
    return overlap


def _follow(
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


def _window_low(lower_rad: FloatArray, upper_rad: FloatArray, periodic: BoolArray) -> FloatArray:
    """Lower end (n,) of the 2 pi window each joint angle is read in: the limits inside it."""
    centre = np.where(periodic, 0.0, 0.5 * (lower_rad + upper_rad))
    return centre - np.pi


def to_window(q_rad: FloatArray, window_low: FloatArray) -> FloatArray:
    """Angles (..., n) mapped into [window_low, window_low + 2 pi)."""
    return window_low + np.mod(q_rad - window_low, TWO_PI)


def _refine_near_limits(
    fibre: Fibre,
    evaluated: _Evaluated,
    loops: list[_Curve],
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    periodic: BoolArray,
    settings: TraceSettings,
    rounds: int = 3,
    pieces: int = 4,
) -> tuple[_Evaluated, list[_Curve]]:
    """Curves with points added where a step may pass through the limits unseen.

    A component shorter than a step can lie between two traced points that are both
    outside the limits. Where the chord of a step, widened by how far a curve bends in
    a step, meets the limit box, the step is split into `pieces` projected points (from
    the Hermite curve through its ends); a few rounds, each looking again only at the
    pieces of the steps the last one split, find components down to about
    h / pieces**rounds long. The evaluated points come back with the added ones.
    """
    low = _window_low(lower_rad, upper_rad, periodic)
    steps = _Steps.of(evaluated, loops)
    added: list[_Evaluated] = []
    added_loop: list[IntArray] = []
    added_key: list[FloatArray] = []  # place in the loop: its step's first point + fraction
    fraction = np.arange(1, pieces) / pieces  # (p - 1,)
    for _ in range(rounds):
        a = to_window(steps.start, low)  # (C, n)
        b = a + steps.delta
        inside_a = np.all(periodic | ((a >= lower_rad) & (a <= upper_rad)), axis=1)
        inside_b = np.all(periodic | ((b >= lower_rad) & (b <= upper_rad)), axis=1)
        # A curve bends off its chord by ~kappa L^2 / 8: a margin of L / 4 per step.
        margin = 0.25 * np.linalg.norm(steps.delta, axis=1, keepdims=True)  # (C, 1)
        meets = _chord_meets_box(a, b, lower_rad - margin, upper_rad + margin, periodic)
        steps = steps.take(meets & ~inside_a & ~inside_b)
        if not len(steps.loop):
            break
        count = len(steps.loop)
        guess, direction = _hermite(
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
        new = _Evaluated.of(projected, unit_tangent(projected.jacobian, previous=direction))
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
        loops[k] = _curve(evaluated, merged, loops[k].closed)
    return evaluated, loops


@dataclass(frozen=True)
class _Steps:
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
    def of(cls, evaluated: _Evaluated, loops: list[_Curve]) -> _Steps:
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
        delta = _torus_difference(evaluated.q_rad[row_b], evaluated.q_rad[row_a])
        return cls(
            loop=loop[step],
            key=place[step].astype(np.float64),
            span=np.ones(len(delta)),
            start=np.concatenate([curve.points for curve in loops])[step],
            delta=delta,
            start_tangent=_along(evaluated.tangent[row_a], delta),
            end_tangent=_along(evaluated.tangent[row_b], delta),
        )

    def take(self, rows: BoolArray) -> _Steps:
        return _Steps(
            self.loop[rows], self.key[rows], self.span[rows], self.start[rows],
            self.delta[rows], self.start_tangent[rows], self.end_tangent[rows],
        )  # fmt: skip

    def split(self, new_rows: IntArray, evaluated: _Evaluated) -> _Steps:
        """Each step as its `pieces` steps through the new points (C, pieces - 1) inside it."""
        count, inner = new_rows.shape
        pieces = inner + 1
        q = evaluated.q_rad[new_rows]  # (C, p - 1, n)
        end = self.start + self.delta
        # The new points in the step's unwrapped coordinates: each moved little from its guess.
        q = self.start[:, None, :] + _torus_difference(q, self.start[:, None, :])
        nodes = np.concatenate([self.start[:, None], q, end[:, None]], axis=1)  # (C, p + 1, n)
        tangents = np.concatenate(
            [self.start_tangent[:, None], evaluated.tangent[new_rows], self.end_tangent[:, None]],
            axis=1,
        )  # (C, p + 1, n)
        delta = np.diff(nodes, axis=1).reshape(-1, nodes.shape[2])  # (C p, n)
        span = np.repeat(self.span / pieces, pieces)
        return _Steps(
            loop=np.repeat(self.loop, pieces),
            key=np.repeat(self.key, pieces) + span * np.tile(np.arange(pieces), count),
            span=span,
            start=nodes[:, :-1].reshape(-1, nodes.shape[2]),
            delta=delta,
            start_tangent=_along(tangents[:, :-1].reshape(delta.shape), delta),
            end_tangent=_along(tangents[:, 1:].reshape(delta.shape), delta),
        )


def _along(tangent: FloatArray, direction: FloatArray) -> FloatArray:  # (K, n) -> (K, n)
    """Each tangent with the sign that points it along `direction`; where the tangent is
    not finite (a rank-deficient Jacobian), the unit direction itself."""
    if not np.isfinite(tangent).all():
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = direction / np.linalg.norm(direction, axis=1, keepdims=True)
        tangent = np.where(np.all(np.isfinite(tangent), axis=1, keepdims=True), tangent, unit)
    return np.where(np.einsum("kn,kn->k", tangent, direction)[:, None] < 0.0, -tangent, tangent)


def _hermite(
    p0: FloatArray,  # (K, n)
    t0: FloatArray,  # (K, n) unit tangent at p0, pointing toward p1
    p1: FloatArray,  # (K, n)
    t1: FloatArray,  # (K, n) unit tangent at p1, pointing away from p0
    s: FloatArray,  # (K,) in [0, 1]
) -> tuple[FloatArray, FloatArray]:  # (K, n) points, (K, n) unit directions of the curve
    """The cubic Hermite curve from p0 to p1 with end tangents t0, t1 scaled by the chord
    length, at parameter s: off a smooth curve by O(L^4) where the chord is off by O(L^2)."""
    chord = p1 - p0  # (K, n)
    length = np.linalg.norm(chord, axis=1, keepdims=True)  # (K, 1)
    s = s[:, None]
    r = 1.0 - s
    point = (
        p0
        + (s * s * (3.0 - 2.0 * s)) * chord
        + (length * s * r * r) * t0
        - (length * s * s * r) * t1
    )
    direction = (
        (6.0 * s * r) * chord
        + (length * r * (1.0 - 3.0 * s)) * t0
        + (length * s * (3.0 * s - 2.0)) * t1
    )
    with np.errstate(invalid="ignore"):
        direction = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    return point, direction


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
    rows: IntArray  # (P,) evaluated points in order
    points: FloatArray  # (P, n) those points unwrapped
    closed: bool
    start_exit: FloatArray | None  # (n,) the outside point before the run (open runs)
    end_exit: FloatArray | None  # (n,) the outside point after the run


def _cut_by_limits(
    loops: list[_Curve], lower_rad: FloatArray, upper_rad: FloatArray, periodic: BoolArray
) -> list[_Run]:
    """The runs of consecutive points of each curve that lie inside the limits."""
    if not loops:
        return []
    low = _window_low(lower_rad, upper_rad, periodic)
    window = to_window(np.concatenate([loop.points for loop in loops]), low)  # (P, n)
    inside_all = np.all(periodic | ((window >= lower_rad) & (window <= upper_rad)), axis=1)
    per_loop = np.split(inside_all, np.cumsum([len(loop.rows) for loop in loops])[:-1])
    runs = []
    for loop, inside in zip(loops, per_loop, strict=True):
        if inside.all():
            runs.append(_Run(loop.rows, loop.points, loop.closed, None, None))
            continue
        if not inside.any():
            continue
        rows, points, closed = loop.rows, loop.points, loop.closed
        if closed:  # rotate so that the loop starts outside: runs never wrap
            shift = int(np.argmin(inside))
            turns = points[-1] + _torus_difference(points[0], points[-1]) - points[0]  # (n,)
            rows = np.concatenate([rows[shift:], rows[:shift]])
            inside = np.concatenate([inside[shift:], inside[:shift]])
            points = np.concatenate([points[shift:], points[:shift] + turns])
        edges = np.diff(np.concatenate([[0], inside.astype(np.int8), [0]]))
        starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        for begin, end in zip(starts.tolist(), stops.tolist(), strict=True):
            before = points[begin - 1] if begin > 0 else (points[-1] if closed else None)
            after = points[end] if end < len(points) else (points[0] if closed else None)
            runs.append(_Run(rows[begin:end], points[begin:end], False, before, after))
    return runs


def _densify(
    fibre: Fibre,
    evaluated: _Evaluated,
    runs: list[_Run],
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    periodic: BoolArray,
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
    low = _window_low(lower_rad, upper_rad, periodic)
    limits, limits_window, limit_of = _limit_points(
        fibre, runs, evaluated, lower_rad, upper_rad, periodic, low, settings
    )
    nodes = evaluated.extended(limits)  # a limit point's row: len(evaluated) + its index
    node_q: list[FloatArray] = []  # per run (N_r, n), unwrapped
    node_rows: list[IntArray] = []  # per run (N_r,) rows of `nodes`
    for r, run in enumerate(runs):
        first, last = limit_of[2 * r], limit_of[2 * r + 1]
        points, rows = run.points, run.rows
        if first >= 0:
            points = np.concatenate([limits.q_rad[first][None], points])
            rows = np.concatenate([[len(evaluated) + first], rows])
        if last >= 0:
            points = np.concatenate([points, limits.q_rad[last][None]])
            rows = np.concatenate([rows, [len(evaluated) + last]])
        if run.closed:  # back to the first point, the short way round
            closing = points[-1:] + _torus_difference(points[:1], points[-1:])
            points, rows = np.concatenate([points, closing]), np.append(rows, rows[0])
        node_q.append(points)
        node_rows.append(rows)
    run_of = np.repeat(np.arange(len(runs)), [len(rows) for rows in node_rows])  # (N,)
    q_node = np.concatenate(node_q)  # (N, n)
    row = np.concatenate(node_rows)  # (N,)
    last_node = np.append(run_of[1:] != run_of[:-1], True)  # (N,) no segment after it
    # Dense layout: each node, then the inner points of the segment to the next node.
    chord = np.diff(q_node, axis=0)  # (N - 1, n)
    inner = np.ceil(np.linalg.norm(chord, axis=1) / (0.9 * settings.path_spacing_rad))
    inner = np.append(np.where(last_node[:-1], 0, np.maximum(inner, 1) - 1), 0).astype(np.int64)
    offset = np.cumsum(inner + 1) - (inner + 1)  # (N,) dense row of each node
    segment = np.repeat(np.arange(len(row)), inner + 1)  # (D,) the node each dense row follows
    part = np.arange(len(segment)) - offset[segment]  # (D,) 0 for the node itself
    between = np.flatnonzero(part > 0)  # (I,)
    k = segment[between]
    guess, direction = _hermite(
        q_node[k],
        _along(nodes.tangent[row[k]], chord[k]),
        q_node[k + 1],
        _along(nodes.tangent[row[k + 1]], chord[k]),
        part[between] / (inner[k] + 1),
    )  # (I, n)
    # The closing node of a closed run repeats its first; a limit point is kept as it is.
    repeated = np.zeros(len(row), dtype=bool)
    repeated[np.flatnonzero(last_node)] = [run.closed for run in runs]
    limit_node = row >= len(evaluated)
    moving_node = np.flatnonzero(~repeated & ~limit_node)
    placed = np.empty((len(segment), n))  # (D, n) where each point was put before Newton
    placed[offset] = q_node
    placed[between] = guess
    known = Projection(q_node[moving_node], nodes.error[row[moving_node]],
                       nodes.jacobian[row[moving_node]])  # fmt: skip
    start = _stack(known, evaluate(fibre, guess)) if len(guess) else known
    tangent = np.concatenate([nodes.tangent[row[moving_node]], direction])
    moved = newton(
        fibre, start, settings.path_iterations, tangent=tangent, until=settings.path_error
    )
    q = placed.copy()
    error = np.empty((len(segment), nodes.error.shape[1]))
    error[offset] = nodes.error[row]  # the limit points' (the others are set next)
    moved_rows = np.concatenate([offset[moving_node], between])
    q[moved_rows], error[moved_rows] = moved.q_rad, moved.error
    # A point that Newton carried away from its place on the path is left out.
    strayed = np.linalg.norm(q - placed, axis=1) > 0.5 * settings.path_spacing_rad
    q = to_window(q, low)
    # A limit point as refined, on its limit exactly (not through its run's coordinates).
    q[offset[limit_node]] = limits_window[row[limit_node] - len(evaluated)]
    inside = np.all(periodic | ((q >= lower_rad) & (q <= upper_rad)), axis=1) & ~strayed
    inside[offset[repeated]] = False
    q = np.where(periodic, wrap_to_pi(q), q)
    run_of_dense = run_of[segment]
    bounds = np.searchsorted(run_of_dense, np.arange(len(runs) + 1))
    pieces = []
    for r, run in enumerate(runs):
        rows = np.arange(bounds[r], bounds[r + 1])
        rows = rows[inside[rows]]  # a point the projection pushed past a limit is left out
        pieces.append(TracedPiece(path_rad=q[rows].reshape(-1, n), error=error[rows],
                                  closed=run.closed))  # fmt: skip
    return pieces


def _stack(*parts: Projection) -> Projection:
    return Projection(
        q_rad=np.concatenate([p.q_rad for p in parts]),
        error=np.concatenate([p.error for p in parts]),
        jacobian=np.concatenate([p.jacobian for p in parts]),
    )


def _limit_points(
    fibre: Fibre, runs: list[_Run], evaluated: _Evaluated, lower_rad: FloatArray,
    upper_rad: FloatArray, periodic: BoolArray, window_low: FloatArray, settings: TraceSettings,
) -> tuple[_Evaluated, FloatArray, IntArray]:  # fmt: skip
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
    found = np.full(2 * len(runs), -1)
    n, m = evaluated.q_rad.shape[1], evaluated.error.shape[1]
    if not inner:
        none = _Evaluated(np.zeros((0, n)), np.zeros((0, m)), np.zeros((0, m, n)), np.zeros((0, n)))
        return none, np.zeros((0, n)), found
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
    refined = project(fibre, guess, iterations=6, locked=locked, until=settings.path_error)
    q = refined.q_rad
    q[rows, joint] = bound  # exactly on the limit (the locked joint did not move)
    inside = np.all(periodic | ((q >= lower_rad) & (q <= upper_rad)), axis=1)
    close = np.linalg.norm(q - a_w, axis=1) <= 2.0 * np.linalg.norm(b_w - a_w, axis=1)
    good = inside & close & (refined.error_norm < 1e-8)
    # Back to the runs' unwrapped coordinates: the same offset as each inner point.
    tangent = unit_tangent(refined.jacobian, previous=b - a)
    points = _Evaluated(q + (a - a_w), refined.error, refined.jacobian, tangent).take(good)
    found[np.asarray(keys)[good]] = np.arange(good.sum())
    return points, q[good], found
