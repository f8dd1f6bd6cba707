"""Stage 5: decide the components on the fibre itself, not by a distance radius.

r = 1: every curve through a sample that reaches the target (inside the limits or not)
is traced whole and cut by the limits (trace/); each piece is a component with its
ordered path, and each accepted sample joins the piece it lies on. Pieces no sample hit
are components too (size 0): they exist, and a planner may want them. Pieces that end
off the limits (a front stopped next to a singular value) are spliced where the
projected local planner walks from one end to the other (splicing.py).
r > 1, and any r = 1 sample that no traced piece passes through: a roadmap whose edges
are checked by the projected local planner (roadmap.py), with nodes added on the chain's
coaxial sets (coaxial.py), where twin branches meet, when components are left apart.

With collisions checked, r = 1 curves are traced whole with collisions aside and then
cut where they enter collision (free_pieces.py): each free piece is a component; r > 1
roadmap nodes are free samples and every step of an edge's walk is checked (the space's
`motion_valid`), so a component is what the robot can move within.

Either way every accepted sample is in exactly one component, and the result says when
the target is near a singular value of the kinematics (sigma_min(J) small on the fibre,
a curve that could not be traced through, or two strands of the traced fibre closer
than the fronts' meeting distance), where components may touch or split and the
structure is ambiguous.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.manifest import ConnectivitySpec
from service.pipeline.arrays import IntArray
from service.pipeline.connect.curves import (
    ON_CURVE_FRACTION,
    Extension,
    owner_path,
    trace_curves,
)
from service.pipeline.connect.free_pieces import free_pieces
from service.pipeline.connect.roadmap import roadmap_components
from service.pipeline.connect.settings import planner_settings, roadmap_settings, splice_settings
from service.pipeline.connect.splicing import attach_by_walk, open_ends, splice_paths
from service.pipeline.connect.trace import MEET_FACTOR, closest_strands_rad
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import min_singular_value
from service.pipeline.rows import Aside
from service.pipeline.space import FibreSpace
from service.pipeline.types import (
    Acceptance,
    Component,
    ComponentPath,
    ComponentRoadmap,
    Correction,
    FibreStructure,
)


@dataclass(frozen=True)
class Connection:
    components: list[Component]
    structure: FibreStructure


def connect(
    space: FibreSpace,
    correction: Correction,
    acceptance: Acceptance,
    spec: ConnectivitySpec,
    deadline: Deadline = NO_DEADLINE,
    traced: Extension | None = None,
) -> Connection:
    """The accepted samples grouped into components decided on the fibre, walking only
    where `space` says a motion is valid (inside its limits, never across its coaxial
    sets off the fibre). For r = 1, `traced` holds curves already traced on the kinematic
    space (while sampling in rounds) and the path each sample on the fibre lies on; None:
    traced here from the samples."""
    deadline.check("connect")
    accepted = np.flatnonzero(acceptance.accepted)  # (K,)
    redundancy = correction.q_rad.shape[1] - correction.jacobian.shape[1]
    min_sigma = np.inf
    if redundancy > 1:  # r = 1: the trace measures sigma_min along every curve instead
        within = correction.jacobian[acceptance.within_tolerance]
        min_sigma = min_singular_value(within, space.fibre.threads)
    components: list[Component] = []
    leftover = accepted
    complete = True
    if redundancy == 1:
        kinematic = space.kinematic()
        found = _curve_components(
            kinematic, correction, acceptance.kinematic(), spec, deadline, traced
        )
        components, leftover = found.components, found.leftover
        complete, min_sigma = found.complete, min(min_sigma, found.min_singular_value)
        if space.collision.active:
            components = free_pieces(space, components, spec.path_spacing_rad)
            leftover = leftover[acceptance.collision_free[leftover]]
        complete &= not np.isfinite(found.strands_rad.result())
    if len(leftover):
        q_leftover = correction.q_rad[leftover]
        planner, roadmap = planner_settings(spec), roadmap_settings(spec)
        joined = roadmap_components(space, q_leftover, planner, roadmap, deadline)
        for label, graph in enumerate(joined.graphs):
            members = leftover[joined.labels == label]
            components.append(_component(correction, acceptance, members, None, graph))
    structure = FibreStructure(
        near_singular=(min_sigma < spec.singular_sigma) or not complete,
        min_singular_value=min_sigma if np.isfinite(min_sigma) else None,
        traced=redundancy == 1,
    )
    return Connection(components=components, structure=structure)


# Path points the strands' closest approach must sweep to run beside the free pieces.
MIN_ASIDE_POINTS = 1000


@dataclass(frozen=True)
class _Curves:
    """r = 1: the traced components, the accepted samples on none of them, whether the
    curves came whole, and the least sigma_min met on them."""

    components: list[Component]
    leftover: IntArray  # (L,) rows of the correction
    complete: bool  # the strands' closest approach aside
    min_singular_value: float
    # The closest approach of two strands of the curves (trace.closest_strands_rad), worked
    # out on another thread while the free pieces are cut: finite, the curves are not
    # resolved there.
    strands_rad: Aside[float]


def _curve_components(
    space: FibreSpace,
    correction: Correction,
    acceptance: Acceptance,
    spec: ConnectivitySpec,
    deadline: Deadline,
    traced: Extension | None,
) -> _Curves:
    """Every curve through the samples within tolerance traced whole and cut by the
    limits (or `traced`, while sampling), pieces the fibre joins spliced, and each
    accepted sample on the path it lies on (or walks to)."""
    accepted = np.flatnonzero(acceptance.accepted)  # (K,)
    q_accepted = correction.q_rad[accepted]
    limits = space.limits
    if traced is None:
        q_within = correction.q_rad[acceptance.within_tolerance]
        traced = trace_curves(space, q_within, q_accepted, spec, deadline)
    curves, owner = traced.curves, traced.owner.copy()  # (K,) attached below
    paths, complete, sigma = curves.paths, curves.complete, curves.min_singular_value
    on_curve_rad = ON_CURVE_FRACTION * spec.path_spacing_rad
    # A piece that ends off the limits is where a front stopped or a cut went wrong:
    # splice the pieces the fibre joins (splicing.py); an end left open means the
    # curve is not whole.
    walk = splice_settings(spec)
    spliced = splice_paths(space, paths, walk, deadline)
    if len(spliced) < len(paths):
        paths = spliced
        owner = owner_path(q_accepted, paths, limits, on_curve_rad)
    stray = np.flatnonzero(owner < 0)
    if len(stray):  # samples on no path: attached where a walk leads to one
        owner[stray] = attach_by_walk(space, q_accepted[stray], paths, walk, deadline)
    complete &= not open_ends(paths, limits)
    # Strands closer than the fronts' meeting distance may have been joined or told
    # apart wrongly: the structure there is not resolved (trace.closest_strands_rad).
    meeting_rad = MEET_FACTOR * spec.trace_step_rad
    strands = [(p.q_rad, p.closed) for p in paths]
    strands_rad = Aside(
        lambda: closest_strands_rad(strands, limits, meeting_rad),
        space.fibre.threads,
        rows=sum(len(q) for q, _ in strands),
        min_rows=MIN_ASIDE_POINTS,
    )
    components = [
        _component(correction, acceptance, accepted[owner == index], path)
        for index, path in enumerate(paths)
    ]
    leftover = accepted[owner < 0]
    complete &= len(leftover) == 0
    return _Curves(components, leftover, bool(complete), sigma, strands_rad)


def _component(
    correction: Correction,
    acceptance: Acceptance,
    members: IntArray,
    path: ComponentPath | None,
    roadmap: ComponentRoadmap | None = None,
) -> Component:
    """The component of the samples `members` (rows of the correction), with the
    clearances the acceptance measured for them."""
    clearance = acceptance.clearance_m
    return Component(
        q_rad=correction.q_rad[members],
        position_error_m=correction.position_error_m[members],
        orientation_error_rad=correction.orientation_error_rad[members],
        path=path,
        clearance_m=None if clearance is None else clearance[members],
        roadmap=roadmap,
    )
