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

from service.manifest import ConnectivitySpec
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.curves import ON_CURVE_FRACTION, owner_path, retraced, traced_paths
from service.pipeline.connect.roadmap import roadmap_labels
from service.pipeline.connect.settings import planner_settings, roadmap_settings, splice_settings
from service.pipeline.connect.splicing import attach_by_walk, open_ends, splice_paths
from service.pipeline.connect.trace import MEET_FACTOR, closest_strands_rad
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import Fibre, smallest_singular_value
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
        paths, complete, sigma = traced_paths(
            fibre, correction.q_rad[acceptance.within_tolerance], lower_rad, upper_rad,
            periodic, spec, tolerance_position_m, tolerance_orientation_rad, deadline,
        )  # fmt: skip
        on_curve_rad = ON_CURVE_FRACTION * spec.path_spacing_rad
        owner = owner_path(correction.q_rad[accepted], paths, periodic, on_curve_rad)
        if (owner < 0).any():
            # Samples on no traced curve: curves the first seeds missed, such as a twin
            # a few hundredths of a radian from a traced one near a singular value.
            more, more_complete, more_sigma = traced_paths(
                fibre, correction.q_rad[accepted[owner < 0]], lower_rad, upper_rad,
                periodic, spec, tolerance_position_m, tolerance_orientation_rad, deadline,
            )  # fmt: skip
            new = [p for p in more if not retraced(p, paths, periodic, on_curve_rad)]
            paths += new
            complete &= more_complete
            sigma = min(sigma, more_sigma)
            owner = owner_path(correction.q_rad[accepted], paths, periodic, on_curve_rad)
        # A piece that ends off the limits is where a front stopped or a cut went wrong:
        # splice the pieces the fibre joins (splicing.py); an end left open means the
        # curve is not whole.
        walk = splice_settings(spec, tolerance_position_m, tolerance_orientation_rad)
        spliced = splice_paths(
            fibre, paths, lower_rad, upper_rad, periodic, walk, deadline, coaxial_sets
        )
        if len(spliced) < len(paths):
            paths = spliced
            owner = owner_path(correction.q_rad[accepted], paths, periodic, on_curve_rad)
        stray = np.flatnonzero(owner < 0)
        if len(stray):  # samples on no path: attached where a walk leads to one
            owner[stray] = attach_by_walk(
                fibre, correction.q_rad[accepted[stray]], paths, lower_rad, upper_rad,
                periodic, walk, deadline, coaxial_sets,
            )  # fmt: skip
        complete &= not open_ends(paths, lower_rad, upper_rad, periodic)
        min_sigma = min(min_sigma, sigma)
        # Strands closer than the fronts' meeting distance may have been joined or told
        # apart wrongly: the structure there is not resolved (trace.closest_strands_rad).
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


def _component(correction: Correction, members: IntArray, path: ComponentPath | None) -> Component:
    return Component(
        q_rad=correction.q_rad[members],
        position_error_m=correction.position_error_m[members],
        orientation_error_rad=correction.orientation_error_rad[members],
        path=path,
    )
