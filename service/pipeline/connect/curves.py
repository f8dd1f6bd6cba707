"""r = 1: the exact paths of every traced curve, and which path each sample lies on.

A traced piece becomes paths of exact points only (cut where a step is no continuation
step), a piece traced twice is kept once, and a sample joins the path whose segments
pass within a fraction of the path spacing of it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.manifest import ConnectivitySpec
from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.settings import trace_settings
from service.pipeline.connect.trace import TracedPiece, trace_fibre
from service.pipeline.correction import error_norms
from service.pipeline.deadline import Deadline
from service.pipeline.joint_space import TWO_PI, JointBox, JointLimits
from service.pipeline.space import FibreSpace
from service.pipeline.types import ComponentPath

# A sample lies on a traced curve when it is within this fraction of the path spacing of
# the path's segments: the chord of a path step of 0.05 rad misses its curve by about
# curvature x 0.05^2 / 8 (3e-4 rad at a curvature of 1), while a twin curve near a
# singular value may pass 0.02 rad from it.
ON_CURVE_FRACTION = 0.2


@dataclass(frozen=True)
class TracedCurves:
    """r = 1: the exact paths of every curve traced so far, whether all came whole, the
    least sigma_min met on them, and every point the trace reached on the whole curves
    (inside the limits or not, at most a trace step apart along each)."""

    paths: list[ComponentPath]
    complete: bool
    min_singular_value: float
    reached_rad: FloatArray  # (R, n)


@dataclass(frozen=True)
class Extension:
    """`extend_curves`' answer: the curves, how many samples were on none of the curves it
    was given, and the path each accepted sample lies on now (-1: none; `owner_path`)."""

    curves: TracedCurves
    strays: int
    owner: IntArray  # (K,)


def trace_curves(
    space: FibreSpace,
    q_within_rad: FloatArray,  # (M, n) samples within tolerance, inside the limits or not
    q_accepted_rad: FloatArray,  # (K, n) those inside the limits (and free)
    spec: ConnectivitySpec,
    deadline: Deadline,
) -> Extension:
    """Every curve through the samples within tolerance, then through any accepted sample
    that none of them passes (`extend_curves`)."""
    curves = traced_paths(space, q_within_rad, spec, deadline)
    return extend_curves(curves, space, q_accepted_rad, spec, deadline)


def on_curves(
    curves: TracedCurves,
    limits: JointLimits,
    q_accepted_rad: FloatArray,  # (K, n)
    spec: ConnectivitySpec,
) -> Extension:
    """The curves as they are, and the path each accepted sample lies on (`owner_path`);
    no sample is traced."""
    on_curve_rad = ON_CURVE_FRACTION * spec.path_spacing_rad
    return Extension(curves, 0, owner_path(q_accepted_rad, curves.paths, limits, on_curve_rad))


def extend_curves(
    curves: TracedCurves,
    space: FibreSpace,
    q_accepted_rad: FloatArray,  # (K, n)
    spec: ConnectivitySpec,
    deadline: Deadline,
    q_outside_rad: FloatArray | None = None,  # (O, n) within tolerance, outside the limits
) -> Extension:
    """The curves and those through the samples on none of them, a path traced again
    kept once; how many samples were on none, and the path each accepted sample is on.
    An accepted sample is on a curve when a path passes it (`owner_path`: a twin a few
    hundredths of a radian from a traced curve near a singular value is not); a sample
    outside the limits, which no path passes, when a point the trace reached lies within
    a trace step of it (its curve may come back inside the limits where no sample fell)."""
    limits = space.limits
    on_curve_rad = ON_CURVE_FRACTION * spec.path_spacing_rad
    owner = owner_path(q_accepted_rad, curves.paths, limits, on_curve_rad)  # (K,)
    q_stray = q_accepted_rad[owner < 0]
    if q_outside_rad is not None and len(q_outside_rad):
        far = off_the_reached(q_outside_rad, curves.reached_rad, spec.trace_step_rad)
        q_stray = np.concatenate([q_stray, q_outside_rad[far]])
    if not len(q_stray):
        return Extension(curves, 0, owner)
    more = traced_paths(space, q_stray, spec, deadline)
    new = [p for p in more.paths if not retraced(p, curves.paths, limits, on_curve_rad)]
    paths = curves.paths + new
    if new:  # a new path may pass nearer to a sample than its old one
        owner = owner_path(q_accepted_rad, paths, limits, on_curve_rad)
    extended = TracedCurves(
        paths,
        curves.complete and more.complete,
        min(curves.min_singular_value, more.min_singular_value),
        np.concatenate([curves.reached_rad, more.reached_rad]),
    )
    return Extension(extended, len(q_stray), owner)


def off_the_reached(
    q_rad: FloatArray,  # (O, n) outside the limits: any turn of each joint
    reached_rad: FloatArray,  # (R, n) points the trace reached, on the torus
    within_rad: float,
) -> BoolArray:  # (O,) no reached point within `within_rad` on the torus
    """Which samples no traced point comes near, on the joint torus (every joint a circle),
    where the trace walks and the kinematics repeats: a sample outside the limits is often
    a turn away from the traced point beside it (a joint at 3.21 rad beside one at -3.04,
    or DLS leaving a joint at 61.7 rad), as far apart in the joint metric of limited
    joints as they are close on the torus."""
    if not len(reached_rad):
        return np.ones(len(q_rad), dtype=bool)
    n = q_rad.shape[1]
    torus = JointBox(
        box_rad=np.full(n, TWO_PI), shift_rad=np.zeros(n), periodic=np.ones(n, dtype=bool)
    )
    distance, _ = torus.tree(reached_rad).query(torus.points(q_rad), k=1)
    return np.asarray(distance, dtype=np.float64).reshape(len(q_rad)) > within_rad


def traced_paths(
    space: FibreSpace,
    q_on_fibre_rad: FloatArray,  # (M, n) seeds' source: samples within tolerance
    spec: ConnectivitySpec,
    deadline: Deadline,
) -> TracedCurves:
    """The exact paths of every curve through the samples, whether all are whole, the
    least sigma_min met on them, and the points the trace reached."""
    trace = trace_fibre(space, q_on_fibre_rad, trace_settings(spec), deadline)
    complete = trace.complete
    paths: list[ComponentPath] = []
    for pieces, whole in all_exact_paths(
        trace.pieces, space, spec.path_spacing_rad, 2.0 * spec.trace_step_rad
    ):
        complete &= whole
        for path in pieces:
            if not duplicate(path, paths, space.limits, spec.path_spacing_rad):
                paths.append(path)
    return TracedCurves(paths, complete, trace.min_singular_value, trace.reached_rad)


def all_exact_paths(
    pieces: list[TracedPiece], space: FibreSpace, spacing_rad: float, cut_rad: float
) -> list[tuple[list[ComponentPath], bool]]:
    """`exact_paths` of every piece, in order. The error norms, the exactness test and
    the steps are measured once over all pieces' points; a piece whose points are all
    exact and whose steps are all continuation steps (the usual case) becomes its one
    path from those, the others go through `exact_paths`."""
    if not pieces:
        return []
    limits = space.limits
    q_all = np.concatenate([p.path_rad for p in pieces])  # (P, n)
    error_all = np.concatenate([p.error for p in pieces])  # (P, m)
    position_all, orientation_all = error_norms(error_all, space.fibre.task)
    exact_all = space.tolerance.within(position_all, orientation_all)  # (P,)
    steps_all = limits.distance(q_all[1:], q_all[:-1])  # (P - 1,) across pieces too
    size = np.array([len(p.path_rad) for p in pieces])
    first = np.cumsum(size) - size
    loops = np.flatnonzero(np.array([p.closed for p in pieces]) & (size > 1))
    closing_all = np.zeros(len(pieces))  # (pieces,) from the last point back to the first
    closing_all[loops] = limits.distance(q_all[first[loops] + size[loops] - 1], q_all[first[loops]])
    inexact_before = np.concatenate([[0], np.cumsum(~exact_all)])
    answers = []
    for index, piece in enumerate(pieces):
        a, b = int(first[index]), int(first[index] + size[index])
        steps = steps_all[a : b - 1]
        longest = float(steps.max(initial=0.0))
        closing = float(closing_all[index])
        inexact = inexact_before[b] > inexact_before[a]
        if inexact or max(longest, closing) > cut_rad or size[index] < 1:
            answers.append(exact_paths(piece, space, spacing_rad, cut_rad))
            continue
        whole = max(longest, closing) <= spacing_rad
        path = ComponentPath(
            q_rad=piece.path_rad,
            position_error_m=position_all[a:b],
            orientation_error_rad=orientation_all[a:b],
            closed=piece.closed,
            arc_length_rad=float(steps.sum()) + closing,
        )
        answers.append(([path], whole))
    return answers


def duplicate(
    path: ComponentPath, paths: list[ComponentPath], limits: JointLimits, spacing_rad: float
) -> bool:
    """The same piece traced twice (two chains over one curve): the same arc length, the
    same ends (open pieces) and, checked last, most points on the other."""
    arc_rad = path.arc_length_rad
    within_rad = max(0.01 * arc_rad, spacing_rad)
    for other in paths:
        if not abs(other.arc_length_rad - arc_rad) <= within_rad:  # (a NaN arc is not alike)
            continue
        if other.closed != path.closed:
            continue
        if not path.closed:
            ends, other_ends = path.q_rad[[0, -1]], other.q_rad[[0, -1]]
            same = limits.distance(ends, other_ends).max() <= spacing_rad
            reversed_ = limits.distance(ends, other_ends[::-1]).max() <= spacing_rad
            if not (same or reversed_):
                continue
        if retraced(path, [other], limits, ON_CURVE_FRACTION * spacing_rad):
            return True
    return False


def retraced(
    path: ComponentPath, paths: list[ComponentPath], limits: JointLimits, on_curve_rad: float
) -> bool:
    """The path is one of `paths` traced again: most of its points lie on one of them."""
    owner = owner_path(path.q_rad, paths, limits, on_curve_rad)
    return bool(np.mean(owner >= 0) > 0.5)


def exact_paths(
    piece: TracedPiece, space: FibreSpace, spacing_rad: float, cut_rad: float
) -> tuple[list[ComponentPath], bool]:
    """The piece as paths of exact points only, and whether it came whole: no point had
    to be left out and no step exceeds the spacing.

    A point Newton could not bring within tolerance (next to a singular point of the
    fibre) is left out rather than returned inexact: the gap it leaves is a continuation
    step, which the trace checked (under 2 h), and the caller flags the target as
    near-singular. A step longer than `cut_rad` (2 h) is no continuation step: fronts
    were chained across two strands (measured on a Panda pose target: 0.58 rad, between
    two exact components), so nothing shows the fibre joins its ends and the path is cut
    there; the splice step joins the pieces again where the local planner walks between
    them (splicing.py).
    """
    limits = space.limits
    position_error, orientation_error = error_norms(piece.error, space.fibre.task)
    exact = space.tolerance.within(position_error, orientation_error)  # (all inside the limits)
    q = piece.path_rad[exact]
    position, orientation = position_error[exact], orientation_error[exact]
    steps = limits.distance(q[1:], q[:-1])  # (P - 1,)
    closing = float(limits.distance(q[-1], q[0])) if piece.closed and len(q) > 1 else 0
    whole = bool(exact.all()) and max(steps.max(initial=0.0), closing) <= spacing_rad
    cuts = np.flatnonzero(steps > cut_rad) + 1  # a piece starts at each
    closed = piece.closed
    if closed and (len(cuts) or closing > cut_rad):  # the loop opens at a long step
        closed = False
        if closing <= cut_rad:  # at the first inner one: the closing step is kept
            start = int(cuts[0])
            turn = np.roll(np.arange(len(q)), -start)
            q, position, orientation = q[turn], position[turn], orientation[turn]
            cuts = cuts[1:] - start
    paths = []
    for rows in np.split(np.arange(len(q)), cuts):
        if not len(rows):
            continue
        arc = float(limits.distance(q[rows][1:], q[rows][:-1]).sum())
        paths.append(
            ComponentPath(
                q_rad=q[rows],
                position_error_m=position[rows],
                orientation_error_rad=orientation[rows],
                closed=closed,
                arc_length_rad=arc + (closing if closed else 0.0),
            )
        )
    return paths, whole


def owner_path(
    q_rad: FloatArray,  # (K, n) accepted samples
    paths: list[ComponentPath],
    limits: JointLimits,
    within_rad: float,
    candidates: int = 4,
) -> IntArray:  # (K,) index of the path each sample lies on, -1 for none
    """Each sample joins the path that passes nearest to it, if within `within_rad`.

    The distance is to the path's segments beside each of the sample's nearest path
    points, not to the points: a sample lies on its own curve between two points up to
    the spacing apart, while a twin curve near a singular value can pass nearer than
    that to it without passing through it. Only candidates within reach of a segment
    within `within_rad` are looked for, so a sample far from every path costs little.
    """
    owner = np.full(len(q_rad), -1)
    if not paths or not len(q_rad):
        return owner
    points = np.concatenate([p.q_rad for p in paths])  # (P, n)
    size = np.array([len(p.q_rad) for p in paths])
    which = np.repeat(np.arange(len(paths)), size)  # (P,) the path of each point
    before, after = np.arange(len(points)) - 1, np.arange(len(points)) + 1  # neighbours ...
    first = np.cumsum(size) - size
    last = first + size - 1
    closed = np.array([p.closed for p in paths])
    before[first] = np.where(closed, last, first)  # ... along each path (a loop wraps)
    after[last] = np.where(closed, first, last)
    # A candidate farther than within_rad + the longest segment is beside no segment within
    # within_rad of the sample: leaving it out changes no owner.
    longest = float(limits.distance(points, points[after]).max(initial=0.0))
    reach = (within_rad + longest) * (1.0 + 1e-9) + 1e-12
    k = min(candidates, len(points))
    nearest = native.nearest_points(points, q_rad, limits.periodic, k, reach)
    distance, point = native.nearest_segment(q_rad, points, before, after, nearest, limits.periodic)
    on_path = distance <= within_rad  # (K,)
    owner[on_path] = which[point[on_path]]
    return owner
