"""Stage 5: decide the components on the fibre itself, not by a distance radius.

r = 1: every curve through a sample that reaches the target (inside the limits or not)
is traced whole and cut by the limits (tracing.py); each piece is a component with its
ordered path, and each accepted sample joins the piece it lies on. Pieces no sample hit
are components too (size 0): they exist, and a planner may want them.
r > 1, and any r = 1 sample that no traced piece passes through: a roadmap whose edges
are checked by the projected local planner (roadmap.py), with nodes added on the chain's
coaxial sets (coaxial.py), where twin branches meet, when components are left apart.

Either way every accepted sample is in exactly one component, and the result says when
the target is near a singular value of the kinematics (sigma_min(J) small on the fibre,
or a curve that could not be traced through), where components may touch or split and
the structure is ambiguous.
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
from service.pipeline.joint_space import JointBox, joint_distance
from service.pipeline.local_planner import PlannerSettings
from service.pipeline.roadmap import RoadmapSettings, roadmap_labels
from service.pipeline.tracing import TracedPiece, TraceSettings, trace_fibre
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
    coaxial_sets: Sequence[CoaxialSet] = (),
) -> Connection:
    """The accepted samples grouped into components decided on the fibre."""
    deadline.check("connect")
    accepted = np.flatnonzero(acceptance.accepted)  # (K,)
    redundancy = correction.q_rad.shape[1] - correction.jacobian.shape[1]
    min_sigma = np.inf
    if redundancy > 1:  # r = 1: the trace measures sigma_min along every curve instead
        sigma = smallest_singular_value(correction.jacobian[acceptance.within_tolerance])
        min_sigma = float(np.nanmin(sigma, initial=np.inf))
    components: list[Component] = []
    leftover = accepted
    complete = True
    if redundancy == 1:
        trace = trace_fibre(
            fibre,
            correction.q_rad[acceptance.within_tolerance],
            lower_rad,
            upper_rad,
            periodic,
            trace_settings(spec),
            deadline,
        )
        complete = trace.complete
        min_sigma = min(min_sigma, trace.min_singular_value)
        paths = []
        for piece in trace.pieces:
            path, all_exact = _exact_path(
                piece, fibre.task, tolerance_position_m, tolerance_orientation_rad, periodic,
                spec.path_spacing_rad,
            )  # fmt: skip
            complete &= all_exact
            if len(path.q_rad):
                paths.append(path)
        owner = _owner_path(correction.q_rad[accepted], paths, periodic, spec.path_spacing_rad)
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


def trace_settings(spec: ConnectivitySpec) -> TraceSettings:
    return TraceSettings(
        step_rad=spec.trace_step_rad,
        max_steps=spec.trace_max_steps,
        seed_spacing_rad=spec.seed_spacing_rad,
        path_spacing_rad=spec.path_spacing_rad,
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


def _exact_path(
    piece: TracedPiece,
    task: TaskSpec,
    tolerance_position_m: float,
    tolerance_orientation_rad: float,
    periodic: BoolArray,
    spacing_rad: float,
) -> tuple[ComponentPath, bool]:
    """The piece as a path of exact points only, and whether it is whole: no point had to
    be left out and no gap exceeds the spacing.

    A point Newton could not bring within tolerance (next to a singular point of the
    fibre) is left out rather than returned inexact; the component stays whole, and the
    caller flags the target as near-singular (the gap there may exceed the spacing).
    """
    position_error, orientation_error = error_norms(piece.error, task)
    exact = (position_error <= tolerance_position_m) & (
        orientation_error <= tolerance_orientation_rad
    )
    q = piece.path_rad[exact]
    gaps = joint_distance(q[1:], q[:-1], periodic)  # (P - 1,)
    if piece.closed and len(q) > 1:
        gaps = np.append(gaps, joint_distance(q[-1], q[0], periodic))
    arc = float(gaps.sum())
    path = ComponentPath(
        q_rad=q,
        position_error_m=position_error[exact],
        orientation_error_rad=orientation_error[exact],
        closed=piece.closed,
        arc_length_rad=arc,
    )
    return path, bool(exact.all()) and gaps.max(initial=0.0) <= spacing_rad


def _owner_path(
    q_rad: FloatArray,  # (K, n) accepted samples
    paths: list[ComponentPath],
    periodic: BoolArray,
    spacing_rad: float,
) -> IntArray:  # (K,) index of the path each sample lies on, -1 for none
    """Each sample joins the path whose nearest point is within the path spacing."""
    owner = np.full(len(q_rad), -1)
    if not paths or not len(q_rad):
        return owner
    points = np.concatenate([p.q_rad for p in paths])
    which = np.concatenate([np.full(len(p.q_rad), i) for i, p in enumerate(paths)])
    box = JointBox.covering(np.concatenate([points, q_rad]), periodic, margin_rad=1.0)
    distance, nearest = box.tree(points).query(box.points(q_rad))
    on_path = distance <= spacing_rad
    owner[on_path] = which[nearest[on_path]]
    return owner


def _component(correction: Correction, members: IntArray, path: ComponentPath | None) -> Component:
    return Component(
        q_rad=correction.q_rad[members],
        position_error_m=correction.position_error_m[members],
        orientation_error_rad=correction.orientation_error_rad[members],
        path=path,
    )
