"""Phase 5: each run with its ends refined onto the limits, densified to the path
spacing on the cubic Hermite curve through its points, every point put on the fibre."""

from __future__ import annotations

import numpy as np

from service.pipeline import native
from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.connect.trace.cut import Runs, to_window, window_low
from service.pipeline.connect.trace.points import (
    Evaluated,
    TracedPiece,
    TraceSettings,
    torus_difference,
)
from service.pipeline.fibre import Fibre, Projection, newton, project, unit_tangent
from service.pipeline.joint_space import JointLimits
from service.pipeline.targets import kernel_orientation


def densify(
    fibre: Fibre,
    evaluated: Evaluated,
    runs: Runs,
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
    them across their limit). The nodes and the guesses between them are laid out by
    compiled code (`native.dense_nodes`, `native.dense_layout`).
    """
    if not len(runs):
        return []
    low = window_low(limits)
    found, found_window, limit_of = limit_points(fibre, runs, evaluated, limits, low, settings)
    nodes = native.dense_nodes(
        runs.points, runs.rows, runs.first, runs.closed, limit_of, found.q_rad,
        len(evaluated), settings.path_spacing_rad,
    )  # fmt: skip
    layout = native.dense_layout(nodes, evaluated.tangent, found.tangent)
    moving = nodes.kind == MOVING
    known_rows = nodes.row[moving]  # every one a traced point: a row of `evaluated`
    guesses, m, n = len(layout.guess_rad), evaluated.error.shape[1], evaluated.q_rad.shape[1]
    # The traced nodes as measured, then the guesses, evaluated in Newton's first pass.
    start = Projection(
        np.concatenate([nodes.q_rad[moving], layout.guess_rad]),
        np.concatenate([evaluated.error[known_rows], np.empty((guesses, m))]),
        np.concatenate([evaluated.jacobian[known_rows], np.empty((guesses, m, n))]),
    )
    fresh = np.arange(len(start.q_rad)) >= len(known_rows)
    tangent = np.concatenate([evaluated.tangent[known_rows], layout.direction])
    moved = newton(
        fibre, start, settings.path_iterations, tangent=tangent, until=settings.path_error,
        fresh=fresh,
    )  # fmt: skip
    # Into the window, a limit point as refined (on its limit exactly, not through its
    # run's coordinates); left out: a point past a limit, one Newton carried away from its
    # place on the path, the closing repeat of a closed run (compiled: `native.dense_finish`).
    q, error, kept = native.dense_finish(
        nodes, layout, np.concatenate([layout.offset[moving], layout.between]), moved.q_rad,
        moved.error, evaluated.error, found.error, found_window, len(runs), low,
        limits.lower_rad, limits.upper_rad, limits.periodic, 0.5 * settings.path_spacing_rad,
    )  # fmt: skip
    ends = np.cumsum(kept)[:-1]  # each run's points that stayed inside, in order
    return [
        TracedPiece(path_rad=path, error=path_error, closed=bool(closed))
        for path, path_error, closed in zip(
            np.split(q, ends), np.split(error, ends), runs.closed, strict=True
        )
    ]


# What each node of `native.dense_nodes` is.
MOVING, LIMIT, REPEATED = 0, 1, 2

# DLS steps that put a run end back on the fibre with its limited joint held.
LIMIT_ITERATIONS = 6


def limit_points(
    fibre: Fibre,
    runs: Runs,
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
    lower_rad, upper_rad, periodic = limits.lower_rad, limits.upper_rad, limits.periodic
    found = np.full(2 * len(runs), -1)
    n, m = evaluated.q_rad.shape[1], evaluated.error.shape[1]
    keys = np.flatnonzero(runs.has_exit.ravel())  # (E,) 2 r for a run's start, 2 r + 1 its end
    if not len(keys):
        none = Evaluated(np.zeros((0, n)), np.zeros((0, m)), np.zeros((0, m, n)), np.zeros((0, n)))
        return none, np.zeros((0, n)), found
    ends = np.stack([runs.points[runs.first[:-1]], runs.points[runs.first[1:] - 1]], axis=1)
    a = ends.reshape(-1, n)[keys]  # (E, n) unwrapped, consecutive on the curve
    b = runs.exits.reshape(-1, n)[keys]
    chain = fibre.chain
    if chain is not None:  # the same points, compiled
        target = fibre.target
        refined_ends = native.limit_points(
            chain.fixed, chain.tip, fibre.task.position_axes, target.position_m,
            kernel_orientation(fibre.task, target), a, b, window_low, lower_rad, upper_rad,
            periodic, LIMIT_ITERATIONS, settings.path_error, fibre.damping,
        )  # fmt: skip
        good = refined_ends.good
        points = Evaluated(
            refined_ends.q_rad, refined_ends.error, refined_ends.jacobian, refined_ends.tangent
        ).take(good)
        found[keys[good]] = np.arange(good.sum())
        return points, refined_ends.q_window_rad[good], found
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
    refined = project(
        fibre, guess, iterations=LIMIT_ITERATIONS, locked=locked, until=settings.path_error
    )
    q = refined.q_rad
    q[rows, joint] = bound  # exactly on the limit (the locked joint did not move)
    inside = limits.contains(q)
    close = np.linalg.norm(q - a_w, axis=1) <= 2.0 * np.linalg.norm(b_w - a_w, axis=1)
    good = inside & close & (refined.error_norm < 1e-8)
    # Back to the runs' unwrapped coordinates: the same offset as each inner point.
    tangent = unit_tangent(refined.jacobian, previous=b - a)
    points = Evaluated(q + (a - a_w), refined.error, refined.jacobian, tangent).take(good)
    found[keys[good]] = np.arange(good.sum())
    return points, q[good], found
