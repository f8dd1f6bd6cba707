"""Stage 5: decide the components on the fibre itself, not by a distance radius.

r = 1: every curve through a sample that reaches the target (inside the limits or not)
is traced whole and cut by the limits (tracing.py); each piece is a component with its
ordered path, and each accepted sample joins the piece it lies on. Pieces no sample hit
are components too (size 0): they exist, and a planner may want them. Pieces that end
off the limits (a front stopped next to a singular value) are spliced where the
projected local planner walks from one end to the other (splicing.py).
r > 1, and any r = 1 sample that no traced piece passes through: a roadmap whose edges
are checked by the projected local planner (roadmap.py), with nodes added on the chain's
coaxial sets (coaxial.py), where twin branches meet, when components are left apart.

Either way every accepted sample is in exactly one component, and the result says when
the target is near a singular value of the kinematics (sigma_min(J) small on the fibre,
a curve that could not be traced through, or two strands of the traced fibre closer
than the fronts' meeting distance), where components may touch or split and the
structure is ambiguous.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from service.manifest import ConnectivitySpec, TaskSpec
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.correction import error_norms
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import Fibre, smallest_singular_value
from service.pipeline.joint_space import JointBox, joint_difference, joint_distance
from service.pipeline.local_planner import PlannerSettings
from service.pipeline.roadmap import RoadmapSettings, roadmap_labels
from service.pipeline.splicing import (
    SpliceSettings,
    attach_by_walk,
    open_ends,
    splice_paths,
)
from service.pipeline.tracing import (
    MEET_FACTOR,
    TracedPiece,
    TraceSettings,
    closest_strands_rad,
    trace_fibre,
)
from service.pipeline.types import (
    Acceptance,
    CoaxialSet,
    Component,
    ComponentPath,
    Correction,
    FibreStructure,
)


@dataclass(frozen=True)
class Connection:
    components: list[Component]
    structure: FibreStructure


def connect(
    fibre: Fibre,
    correction: Correction,
    acceptance: Acceptance,
    lower_rad: FloatArray,  # (n,)
    upper_rad: FloatArray,  # (n,)
    periodic: BoolArray,  # (n,)
    spec: ConnectivitySpec,
    tolerance_position_m: float,
    tolerance_orientation_rad: float,
    deadline: Deadline = NO_DEADLINE,
    *,
    coaxial_sets: Sequence[CoaxialSet],
) -> Connection:
    """The accepted samples grouped into components decided on the fibre; `coaxial_sets`
    (the model's, `SmmModel.coaxial_sets`) has no default, so that every caller, the
    evaluation's baselines and tools included, connects as the service does."""
    deadline.check("connect")
    accepted = np.flatnonzero(acceptance.accepted)  # (K,)
    redundancy = correction.q_rad.shape[1] - correction.jacobian.shape[1]
    min_sigma = np.inf
    if redundancy > 1:  # r = 1: the trace measures sigma_min along every curve instead
        sigmas = smallest_singular_value(correction.jacobian[acceptance.within_tolerance])
        min_sigma = float(np.nanmin(sigmas, initial=np.inf))
    components: list[Component] = []
    leftover = accepted
    complete = True
    if redundancy == 1:
        paths, complete, sigma = _traced_paths(
            fibre, correction.q_rad[acceptance.within_tolerance], lower_rad, upper_rad,
            periodic, spec, tolerance_position_m, tolerance_orientation_rad, deadline,
        )  # fmt: skip
        on_curve_rad = ON_CURVE_FRACTION * spec.path_spacing_rad
        owner = _owner_path(correction.q_rad[accepted], paths, periodic, on_curve_rad)
        if (owner < 0).any():
            # Samples on no traced curve: curves the first seeds missed, such as a twin
            # a few hundredths of a radian from a traced one near a singular value.
            more, more_complete, more_sigma = _traced_paths(
                fibre, correction.q_rad[accepted[owner < 0]], lower_rad, upper_rad,
                periodic, spec, tolerance_position_m, tolerance_orientation_rad, deadline,
            )  # fmt: skip
            new = [p for p in more if not _retraced(p, paths, periodic, on_curve_rad)]
            paths += new
            complete &= more_complete
            sigma = min(sigma, more_sigma)
            owner = _owner_path(correction.q_rad[accepted], paths, periodic, on_curve_rad)
        # A piece that ends off the limits is where a front stopped or a cut went wrong:
        # splice the pieces the fibre joins (splicing.py); an end left open means the
        # curve is not whole.
        walk = splice_settings(spec, tolerance_position_m, tolerance_orientation_rad)
        spliced = splice_paths(
            fibre, paths, lower_rad, upper_rad, periodic, walk, deadline, coaxial_sets
        )
        if len(spliced) < len(paths):
            paths = spliced
            owner = _owner_path(correction.q_rad[accepted], paths, periodic, on_curve_rad)
        stray = np.flatnonzero(owner < 0)
        if len(stray):  # samples on no path: attached where a walk leads to one
            owner[stray] = attach_by_walk(
                fibre, correction.q_rad[accepted[stray]], paths, lower_rad, upper_rad,
                periodic, walk, deadline, coaxial_sets,
            )  # fmt: skip
        complete &= not open_ends(paths, lower_rad, upper_rad, periodic)
        min_sigma = min(min_sigma, sigma)
        # Strands closer than the fronts' meeting distance may have been joined or told
        # apart wrongly: the structure there is not resolved (tracing.closest_strands_rad).
        strands_rad = closest_strands_rad(
            [(p.q_rad, p.closed) for p in paths], periodic, MEET_FACTOR * spec.trace_step_rad
        )
        complete &= not np.isfinite(strands_rad)
        for index, path in enumerate(paths):
            members = accepted[owner == index]
            components.append(_component(correction, members, path))
        leftover = accepted[owner < 0]
        complete &= len(leftover) == 0
    if len(leftover):
        labels = roadmap_labels(
            fibre, correction.q_rad[leftover], lower_rad, upper_rad, periodic,
            planner_settings(spec), roadmap_settings(spec), deadline,
            coaxial=coaxial_sets,
        )  # fmt: skip
        for label in range(labels.max() + 1):
            components.append(_component(correction, leftover[labels == label], None))
    structure = FibreStructure(
        near_singular=(min_sigma < spec.singular_sigma) or not complete,
        min_singular_value=min_sigma if np.isfinite(min_sigma) else None,
        traced=redundancy == 1,
    )
    return Connection(components=components, structure=structure)


# A sample lies on a traced curve when it is within this fraction of the path spacing of
# the path's segments: the chord of a path step of 0.05 rad misses its curve by about
# curvature x 0.05^2 / 8 (3e-4 rad at a curvature of 1), while a twin curve near a
# singular value may pass 0.02 rad from it.
ON_CURVE_FRACTION = 0.2
# The splice walk steps h / this: under the closest twins the walk must tell apart (a hop
# is a step longer than lambda x delta; the Panda's stopped ends lie 0.005 to 0.09 rad
# apart at h = 0.15).
SPLICE_DIVISIONS = 32


def _traced_paths(
    fibre: Fibre,
    q_on_fibre_rad: FloatArray,  # (M, n) seeds' source: samples within tolerance
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    periodic: BoolArray,
    spec: ConnectivitySpec,
    tolerance_position_m: float,
    tolerance_orientation_rad: float,
    deadline: Deadline,
) -> tuple[list[ComponentPath], bool, float]:
    """The exact paths of every curve through the samples; whether all are whole; the
    least sigma_min met on them."""
    trace = trace_fibre(
        fibre, q_on_fibre_rad, lower_rad, upper_rad, periodic, trace_settings(spec), deadline
    )
    complete = trace.complete
    paths: list[ComponentPath] = []
    for piece in trace.pieces:
        pieces, whole = _exact_paths(
            piece, fibre.task, tolerance_position_m, tolerance_orientation_rad, periodic,
            spec.path_spacing_rad, 2.0 * spec.trace_step_rad,
        )  # fmt: skip
        complete &= whole
        for path in pieces:
            if not _duplicate(path, paths, periodic, spec.path_spacing_rad):
                paths.append(path)
    return paths, complete, trace.min_singular_value


def _duplicate(
    path: ComponentPath, paths: list[ComponentPath], periodic: BoolArray, spacing_rad: float
) -> bool:
    """The same piece traced twice (two chains over one curve): the same arc length, the
    same ends (open pieces) and, checked last, most points on the other."""
    if not paths:
        return False
    arcs = np.array([p.arc_length_rad for p in paths])  # (P,)
    alike = np.abs(arcs - path.arc_length_rad) <= max(0.01 * path.arc_length_rad, spacing_rad)
    for index in np.flatnonzero(alike).tolist():
        other = paths[index]
        if other.closed != path.closed:
            continue
        if not path.closed:
            ends, other_ends = path.q_rad[[0, -1]], other.q_rad[[0, -1]]
            same = joint_distance(ends, other_ends, periodic).max() <= spacing_rad
            reversed_ = joint_distance(ends, other_ends[::-1], periodic).max() <= spacing_rad
            if not (same or reversed_):
                continue
        if _retraced(path, [other], periodic, ON_CURVE_FRACTION * spacing_rad):
            return True
    return False


def _retraced(
    path: ComponentPath, paths: list[ComponentPath], periodic: BoolArray, on_curve_rad: float
) -> bool:
    """The path is one of `paths` traced again: most of its points lie on one of them."""
    owner = _owner_path(path.q_rad, paths, periodic, on_curve_rad)
    return bool(np.mean(owner >= 0) > 0.5)


def trace_settings(spec: ConnectivitySpec) -> TraceSettings:
    return TraceSettings(
        step_rad=spec.trace_step_rad,
        max_steps=spec.trace_max_steps,
        seed_spacing_rad=spec.seed_spacing_rad,
        path_spacing_rad=spec.path_spacing_rad,
    )


def splice_settings(
    spec: ConnectivitySpec, tolerance_position_m: float, tolerance_orientation_rad: float
) -> SpliceSettings:
    """Open ends within one trace step are candidates; the walk between them is the local
    planner's (lambda, tolerance) at steps of h / SPLICE_DIVISIONS."""
    return SpliceSettings(
        reach_rad=spec.trace_step_rad,
        planner=PlannerSettings(
            delta_rad=spec.trace_step_rad / SPLICE_DIVISIONS,
            lambda_=spec.lambda_,
            projection_tolerance=spec.projection_tolerance,
        ),
        spacing_rad=spec.path_spacing_rad,
        tolerance_position_m=tolerance_position_m,
        tolerance_orientation_rad=tolerance_orientation_rad,
    )


def planner_settings(spec: ConnectivitySpec) -> PlannerSettings:
    return PlannerSettings(
        delta_rad=spec.delta_rad,
        lambda_=spec.lambda_,
        projection_tolerance=spec.projection_tolerance,
    )


def roadmap_settings(spec: ConnectivitySpec) -> RoadmapSettings:
    return RoadmapSettings(
        neighbours=spec.neighbours,
        radius_rad=spec.radius_rad,
        bridge_radius_rad=spec.bridge_radius_rad,
        bridge_pairs=spec.bridge_pairs,
        bridge_lambda=spec.bridge_lambda,
    )


def _exact_paths(
    piece: TracedPiece,
    task: TaskSpec,
    tolerance_position_m: float,
    tolerance_orientation_rad: float,
    periodic: BoolArray,
    spacing_rad: float,
    cut_rad: float,
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
    position_error, orientation_error = error_norms(piece.error, task)
    exact = (position_error <= tolerance_position_m) & (
        orientation_error <= tolerance_orientation_rad
    )
    q = piece.path_rad[exact]
    position, orientation = position_error[exact], orientation_error[exact]
    steps = joint_distance(q[1:], q[:-1], periodic)  # (P - 1,)
    closing = float(joint_distance(q[-1], q[0], periodic)) if piece.closed and len(q) > 1 else 0
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
        arc = float(joint_distance(q[rows][1:], q[rows][:-1], periodic).sum())
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


def _owner_path(
    q_rad: FloatArray,  # (K, n) accepted samples
    paths: list[ComponentPath],
    periodic: BoolArray,
    within_rad: float,
    candidates: int = 4,
) -> IntArray:  # (K,) index of the path each sample lies on, -1 for none
    """Each sample joins the path that passes nearest to it, if within `within_rad`.

    The distance is to the path's segments beside each of the sample's nearest path
    points, not to the points: a sample lies on its own curve between two points up to
    the spacing apart, while a twin curve near a singular value can pass nearer than
    that to it without passing through it.
    """
    owner = np.full(len(q_rad), -1)
    if not paths or not len(q_rad):
        return owner
    points = np.concatenate([p.q_rad for p in paths])  # (P, n)
    which = np.concatenate([np.full(len(p.q_rad), i) for i, p in enumerate(paths)])
    before, after = np.arange(len(points)) - 1, np.arange(len(points)) + 1  # neighbours ...
    first = np.cumsum([0] + [len(p.q_rad) for p in paths[:-1]])
    last = first + np.array([len(p.q_rad) for p in paths]) - 1
    closed = np.array([p.closed for p in paths])
    before[first] = np.where(closed, last, first)  # ... along each path (a loop wraps)
    after[last] = np.where(closed, first, last)
    box = JointBox.covering(np.concatenate([points, q_rad]), periodic, margin_rad=1.0)
    k = min(candidates, len(points))
    _, nearest = box.tree(points).query(box.points(q_rad), k=k)  # (K, k)
    nearest = nearest.reshape(len(q_rad), k)
    distance = np.minimum(
        _segment_distance(q_rad, points[nearest], points[before[nearest]], periodic),
        _segment_distance(q_rad, points[nearest], points[after[nearest]], periodic),
    )  # (K, k)
    best = np.argmin(distance, axis=1)
    rows = np.arange(len(q_rad))
    on_path = distance[rows, best] <= within_rad
    owner[on_path] = which[nearest[rows, best]][on_path]
    return owner


def _segment_distance(
    q_rad: FloatArray,  # (K, n)
    a_rad: FloatArray,  # (K, k, n) segment starts
    b_rad: FloatArray,  # (K, k, n) segment ends
    periodic: BoolArray,
) -> FloatArray:  # (K, k) joint-metric distance from each q to each segment a-b
    along = joint_difference(b_rad, a_rad, periodic)  # (K, k, n)
    offset = joint_difference(q_rad[:, None, :], a_rad, periodic)
    length2 = np.einsum("kcn,kcn->kc", along, along)
    fraction = np.clip(
        np.einsum("kcn,kcn->kc", offset, along) / np.maximum(length2, 1e-300), 0.0, 1.0
    )
    return np.linalg.norm(offset - fraction[..., None] * along, axis=2)


def _component(correction: Correction, members: IntArray, path: ComponentPath | None) -> Component:
    return Component(
        q_rad=correction.q_rad[members],
        position_error_m=correction.position_error_m[members],
        orientation_error_rad=correction.orientation_error_rad[members],
        path=path,
    )
