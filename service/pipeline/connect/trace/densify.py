"""Phase 5: each run with its ends refined onto the limits, densified to the path
spacing on the cubic Hermite curve through its points, every point put on the fibre."""

from __future__ import annotations

import numpy as np

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.trace.limits import Run, along, hermite, to_window, window_low
from service.pipeline.connect.trace.points import (
    Evaluated,
    TracedPiece,
    TraceSettings,
    torus_difference,
)
from service.pipeline.fibre import Fibre, Projection, evaluate, newton, project, unit_tangent
from service.pipeline.joint_space import wrap_to_pi


def densify(
    fibre: Fibre,
    evaluated: Evaluated,
    runs: list[Run],
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
    low = window_low(lower_rad, upper_rad, periodic)
    limits, limits_window, limit_of = limit_points(
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
            closing = points[-1:] + torus_difference(points[:1], points[-1:])
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
    guess, direction = hermite(
        q_node[k],
        along(nodes.tangent[row[k]], chord[k]),
        q_node[k + 1],
        along(nodes.tangent[row[k + 1]], chord[k]),
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
    start = stack(known, evaluate(fibre, guess)) if len(guess) else known
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


def stack(*parts: Projection) -> Projection:
    return Projection(
        q_rad=np.concatenate([p.q_rad for p in parts]),
        error=np.concatenate([p.error for p in parts]),
        jacobian=np.concatenate([p.jacobian for p in parts]),
    )


def limit_points(
    fibre: Fibre, runs: list[Run], evaluated: Evaluated, lower_rad: FloatArray,
    upper_rad: FloatArray, periodic: BoolArray, window_low: FloatArray, settings: TraceSettings,
) -> tuple[Evaluated, FloatArray, IntArray]:  # fmt: skip
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
    inside = np.all(periodic | ((q >= lower_rad) & (q <= upper_rad)), axis=1)
    close = np.linalg.norm(q - a_w, axis=1) <= 2.0 * np.linalg.norm(b_w - a_w, axis=1)
    good = inside & close & (refined.error_norm < 1e-8)
    # Back to the runs' unwrapped coordinates: the same offset as each inner point.
    tangent = unit_tangent(refined.jacobian, previous=b - a)
    points = Evaluated(q + (a - a_w), refined.error, refined.jacobian, tangent).take(good)
    found[np.asarray(keys)[good]] = np.arange(good.sum())
    return points, q[good], found
