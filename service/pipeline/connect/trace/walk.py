"""Phase 2: fronts walk each curve both ways from every seed by predictor-corrector
continuation, in lockstep, until they meet a front coming the other way.

On a serial chain the loop runs compiled (`native.walk`: the same steps, tests, meetings
and order, pinned bitwise to this numpy loop, which any other kinematics takes)."""

from __future__ import annotations

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.trace.points import Curves, Evaluated, TraceSettings, torus_difference
from service.pipeline.connect.trace.strands import chain as chain_fronts
from service.pipeline.deadline import Deadline
from service.pipeline.fibre import Fibre, project, smallest_singular_value, unit_tangent
from service.pipeline.targets import kernel_orientation

# sigma_min(J) below which two meeting fronts may be on twin curves (the iiwa's elbow
# twins at q4 = +-0.015, 0.03 rad apart, have sigma_min ~ 0.006; on regular pose targets
# the fibre's least sigma_min is ~0.1).
TWIN_SIGMA = 0.05

TWIN_OFFSET = 0.05  # x h: the chord's offset from the mean tangent that marks twins

MEET_FACTOR = 1.1  # x h: fronts whose ends come this close may meet


def walk_fronts(
    fibre: Fibre,
    seeds: Evaluated,  # (S,) on the fibre, with their tangents
    settings: TraceSettings,
    deadline: Deadline,
) -> tuple[Evaluated, Curves, bool]:
    """Fronts in lockstep from every seed both ways; every point they reached (the seeds
    first, then the fronts' points), the curves through them, and whether all closed.

    Each front has its own step: a step that fails (the corrector does not converge, pulls
    the prediction by more than a quarter step, which is how a step lands on a nearby
    curve, or the tangent turns sharply) is retried at half the length, down to 1/16 of
    h, and a good step lets the next one grow back by 1.5x: sharp bends near a singular
    value are walked, not jumped.
    """
    num_seeds = len(seeds)  # front 2i leaves seed i along +t, front 2i + 1 along -t
    q = np.repeat(seeds.q_rad, 2, axis=0)  # (F, n) front ends
    tangent = np.repeat(seeds.tangent, 2, axis=0) * np.tile([1.0, -1.0], num_seeds)[:, None]
    jacobian = np.repeat(seeds.jacobian, 2, axis=0)  # (F, m, n) at the front ends
    chain = fibre.chain
    if chain is None:
        reached, by_front, partner = _walk(fibre, q, tangent, jacobian, settings, deadline)
    else:  # the same steps, compiled (native.walk)
        target = fibre.target
        walked = native.walk(
            chain.fixed, chain.tip, fibre.task.position_axes, target.position_m,
            kernel_orientation(fibre.task, target), q, tangent, jacobian,
            native.WalkRules(
                step_rad=settings.step_rad,
                corrector_iterations=settings.corrector_iterations,
                max_steps=settings.max_steps,
                meet_factor=MEET_FACTOR,
                twin_sigma=TWIN_SIGMA,
                twin_offset=TWIN_OFFSET,
            ),
            fibre.damping, deadline.expires_at_s,
        )  # fmt: skip
        if walked.expired:
            deadline.check("connect")
        reached = Evaluated(walked.q_rad, walked.error, walked.jacobian, walked.tangent)
        by_front, partner = walked.front, walked.partner
    evaluated = seeds.extended(reached)
    curves = chain_fronts(evaluated, num_seeds, by_front, partner)
    # A front that gave up but was met by another leaves its curve closed all the same.
    return evaluated, curves, bool(curves.closed.all())


def _walk(
    fibre: Fibre,
    q: FloatArray,  # (F, n) front ends, updated as they move
    tangent: FloatArray,  # (F, n)
    jacobian: FloatArray,  # (F, m, n)
    settings: TraceSettings,
    deadline: Deadline,
) -> tuple[Evaluated, IntArray, IntArray]:
    """The lockstep loop in numpy (any kinematics): every point the fronts moved to, in
    the order they moved, the front that moved to each, and the front each met (-1: none)."""
    num_fronts = len(q)
    h = settings.step_rad
    step_rad = np.full(num_fronts, h)  # (F,)
    alive = np.ones(num_fronts, dtype=bool)
    partner = np.full(num_fronts, -1)  # (F,) the front each met, end to end
    reached: list[Evaluated] = []  # per step, the points the fronts moved to
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
        reached.append(Evaluated.of(corrected, new_tangent).take(moved))
        reached_by.append(index)
        q[index], tangent[index] = reached[-1].q_rad, reached[-1].tangent
        jacobian[index] = reached[-1].jacobian
        step_rad[index] = np.minimum(h, 1.5 * step_rad[index])
        meet(q, previous, tangent, jacobian, step_rad, h, alive, partner)
    if not reached:
        empty = Evaluated(q[:0], np.zeros((0, jacobian.shape[1])), jacobian[:0], q[:0])
        return empty, np.zeros(0, dtype=np.int64), partner
    return reached[0].extended(*reached[1:]), np.concatenate(reached_by), partner


def meet(
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
    chord = torus_difference(q[b], q[a])  # (P, n) from a's end to b's end
    length = np.linalg.norm(chord, axis=1)
    before = np.linalg.norm(torus_difference(previous[b], previous[a]), axis=1)
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
