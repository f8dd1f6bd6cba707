"""Describe each component for the response: representative, bounds, errors, reference
distance, and (when collisions are checked) its clearance and safest configuration.

Every accepted member counts in `size` (a 1-D component found only by tracing has size
0 and is described by its path); when the client caps the configurations returned per
component, the ones returned are chosen by farthest-point sampling so that they
still cover the whole component.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from service.pipeline.arrays import FloatArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.joint_space import JointLimits
from service.pipeline.types import Component, ComponentSummary


def joint_mean(q_rad: FloatArray, limits: JointLimits) -> FloatArray:
    """Mean (n,) of configurations (k, n): circular mean on periodic joints, plain elsewhere."""
    circular = np.arctan2(np.sin(q_rad).mean(axis=0), np.cos(q_rad).mean(axis=0))
    return np.where(limits.periodic, circular, q_rad.mean(axis=0))


def farthest_point_subset(
    q_rad: FloatArray,
    limits: JointLimits,
    start: int,
    count: int,
    deadline: Deadline = NO_DEADLINE,
) -> FloatArray:
    """`count` members (count, n) of q_rad (k, n), greedily each farthest from those chosen."""
    if count >= len(q_rad):
        return q_rad
    chosen = [start]
    distance = limits.distance(q_rad, q_rad[start])  # (k,)
    for _ in range(count - 1):
        deadline.check("summarise")
        nxt = int(np.argmax(distance))
        chosen.append(nxt)
        distance = np.minimum(distance, limits.distance(q_rad, q_rad[nxt]))
    return q_rad[np.asarray(chosen)]


def measured(components: list[Component], collision: CollisionCheck) -> list[Component]:
    """The components with every member's and path point's clearance, the ones not yet
    measured measured in one call; unchanged when nothing is checked."""
    if not collision.active:
        return components
    parts = [c.q_rad for c in components if c.clearance_m is None]
    parts += [c.path.q_rad for c in components if c.path and c.path.clearance_m is None]
    clearance = iter(collision.clearances_m(parts))
    members = [
        c if c.clearance_m is not None else replace(c, clearance_m=next(clearance))
        for c in components
    ]
    return [
        c
        if c.path is None or c.path.clearance_m is not None
        else replace(c, path=replace(c.path, clearance_m=next(clearance)))
        for c in members
    ]


def clearance_along(component: Component) -> tuple[float, FloatArray, float] | None:
    """(least clearance, configuration (n,) of greatest clearance, its clearance) over the
    component's members and path points, as measured (`measured`); None when nothing was."""
    if component.clearance_m is None:
        return None
    q, clearance = component.q_rad, component.clearance_m  # (k, n), (k,)
    path = component.path
    if path is not None and path.clearance_m is not None:
        q = np.concatenate([q, path.q_rad])
        clearance = np.concatenate([clearance, path.clearance_m])
    if not len(clearance):
        return None
    best = int(np.argmax(clearance))
    return float(clearance.min()), q[best], float(clearance[best])


def summarise(
    component: Component,
    limits: JointLimits,
    reference_rad: FloatArray | None,
    max_configurations: int | None,
    include_path: bool,
    deadline: Deadline = NO_DEADLINE,
) -> ComponentSummary:
    """The response's view of a component; bounds, errors and the reference distance cover
    its samples and (r = 1) every point of its path."""
    q = component.q_rad  # (k, n)
    path = component.path
    every = q if path is None else np.concatenate([q, path.q_rad])  # (k + P, n)
    position_error = component.position_error_m
    orientation_error = component.orientation_error_rad
    if path is not None:
        position_error = np.concatenate([position_error, path.position_error_m])
        orientation_error = np.concatenate([orientation_error, path.orientation_error_rad])
    # The representative is a sample when there is one, else the path point nearest the mean.
    pool = q if len(q) else every
    centre = joint_mean(pool, limits)
    representative = int(np.argmin(limits.distance(pool, centre)))
    configurations = (
        q
        if max_configurations is None or not len(q)
        else farthest_point_subset(q, limits, representative, max_configurations, deadline)
    )
    distance_to_reference = None
    nearest = None
    if reference_rad is not None:
        distances = limits.distance(every, reference_rad)  # (k + P,)
        best = int(np.argmin(distances))
        distance_to_reference = float(distances[best])
        nearest = every[best]
    clearance = clearance_along(component)
    return ComponentSummary(
        size=len(q),
        representative_rad=pool[representative],
        configurations_rad=configurations,
        joint_min_rad=every.min(axis=0),
        joint_max_rad=every.max(axis=0),
        max_position_error_m=float(position_error.max()),
        max_orientation_error_rad=float(orientation_error.max()),
        distance_to_reference_rad=distance_to_reference,
        nearest_to_reference_rad=nearest,
        arc_length_rad=None if path is None else path.arc_length_rad,
        closed=None if path is None else path.closed,
        ends=None if path is None or path.closed else path.ends,
        path=path if include_path else None,
        clearance_m=None if clearance is None else clearance[0],
        safest_rad=None if clearance is None else clearance[1],
        safest_clearance_m=None if clearance is None else clearance[2],
    )


def summarise_all(
    components: list[Component],
    limits: JointLimits,
    collision: CollisionCheck,
    reference_rad: FloatArray | None,
    max_configurations: int | None,
    include_paths: bool,
    deadline: Deadline = NO_DEADLINE,
) -> list[ComponentSummary]:
    """Summaries ordered by distance to the reference when given, else by size (largest first,
    then the longest path)."""
    if reference_rad is not None:
        reference_rad = limits.wrap(reference_rad)
    summaries = [
        summarise(c, limits, reference_rad, max_configurations, include_paths, deadline)
        for c in measured(components, collision)
    ]
    if reference_rad is not None:
        return sorted(summaries, key=lambda s: (s.distance_to_reference_rad, -s.size))
    return sorted(summaries, key=lambda s: (-s.size, -(s.arc_length_rad or 0.0)))
