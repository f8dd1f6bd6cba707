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

from service.pipeline.arrays import FloatArray, IntArray
from service.pipeline.collision.check import CollisionCheck
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.joint_space import JointLimits
from service.pipeline.types import Component, ComponentSummary


def joint_mean(q_rad: FloatArray, limits: JointLimits) -> FloatArray:
    """Mean (n,) of configurations (k, n): circular mean on periodic joints, plain elsewhere."""
    return segment_joint_mean(q_rad, np.zeros(1, dtype=np.int64), np.array([len(q_rad)]), limits)[0]


def _rows(components: list[Component], field: str) -> FloatArray:
    """`field` of every component's members then of its path's points, all components."""
    return np.concatenate([
        part
        for c in components
        for part in [getattr(c, field)] + ([] if c.path is None else [getattr(c.path, field)])
    ])  # fmt: skip


def segment_joint_mean(
    q_rad: FloatArray,  # (Q, n) segments of consecutive rows
    start: IntArray,  # (C,) each segment's first row
    size: IntArray,  # (C,) its rows, at least one
    limits: JointLimits,
) -> FloatArray:  # (C, n)
    """`joint_mean` of each segment, in one pass over all rows: the circular mean (the
    angle of the mean of cos and sin) on periodic joints, the plain mean elsewhere. Each
    segment's sums are its own rows' (the same numbers as the segment alone)."""
    count = size[:, None].astype(np.float64)
    sin = np.add.reduceat(np.sin(q_rad), start, axis=0) / count
    cos = np.add.reduceat(np.cos(q_rad), start, axis=0) / count
    plain = np.add.reduceat(q_rad, start, axis=0) / count
    return np.where(limits.periodic, np.arctan2(sin, cos), plain)


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
    components: list[Component],
    limits: JointLimits,
    reference_rad: FloatArray | None,
    max_configurations: int | None,
    include_path: bool,
    deadline: Deadline = NO_DEADLINE,
    include_roadmap: bool = False,
) -> list[ComponentSummary]:
    """The response's view of each component; bounds, errors and the reference distance
    cover its samples and (r = 1) every point of its path. Each reduction runs once over
    every component's rows (a segment per component), not once per component: an iiwa14
    pose answer has about 20 components."""
    if not components:
        return []
    # Each component's rows, all components in order: its members, then its path points.
    every = _rows(components, "q_rad")  # (R, n)
    position_error = _rows(components, "position_error_m")  # (R,)
    orientation_error = _rows(components, "orientation_error_rad")
    size = np.array(
        [len(c.q_rad) + (0 if c.path is None else len(c.path.q_rad)) for c in components]
    )
    start = np.cumsum(size) - size  # (C,)
    # The representative is a sample when there is one, else the path point nearest the mean.
    members = np.array([len(c.q_rad) for c in components])
    pool_size = np.where(members > 0, members, size)  # (C,)
    pool_start = np.cumsum(pool_size) - pool_size
    pool_rows = np.repeat(start - pool_start, pool_size) + np.arange(pool_size.sum())
    pool = every[pool_rows]  # (Q, n)
    centre = segment_joint_mean(pool, pool_start, pool_size, limits)  # (C, n)
    to_centre = limits.distance(pool, np.repeat(centre, pool_size, axis=0))  # (Q,)
    joint_min = np.minimum.reduceat(every, start, axis=0)  # (C, n)
    joint_max = np.maximum.reduceat(every, start, axis=0)
    max_position = np.maximum.reduceat(position_error, start)  # (C,)
    max_orientation = np.maximum.reduceat(orientation_error, start)
    to_reference = None if reference_rad is None else limits.distance(every, reference_rad)
    summaries = []
    for index, component in enumerate(components):
        a, k = int(pool_start[index]), int(pool_size[index])
        representative = int(np.argmin(to_centre[a : a + k]))
        q = component.q_rad
        configurations = (
            q
            if max_configurations is None or not len(q)
            else farthest_point_subset(q, limits, representative, max_configurations, deadline)
        )
        distance_to_reference = None
        nearest = None
        if to_reference is not None:
            first, count = int(start[index]), int(size[index])
            best = int(np.argmin(to_reference[first : first + count]))
            distance_to_reference = float(to_reference[first + best])
            nearest = every[first + best]
        clearance = clearance_along(component)
        path = component.path
        summaries.append(
            ComponentSummary(
                size=len(q),
                representative_rad=pool[a + representative],
                configurations_rad=configurations,
                joint_min_rad=joint_min[index],
                joint_max_rad=joint_max[index],
                max_position_error_m=float(max_position[index]),
                max_orientation_error_rad=float(max_orientation[index]),
                distance_to_reference_rad=distance_to_reference,
                nearest_to_reference_rad=nearest,
                arc_length_rad=None if path is None else path.arc_length_rad,
                closed=None if path is None else path.closed,
                ends=None if path is None or path.closed else path.ends,
                path=path if include_path else None,
                roadmap=component.roadmap if include_roadmap else None,
                clearance_m=None if clearance is None else clearance[0],
                safest_rad=None if clearance is None else clearance[1],
                safest_clearance_m=None if clearance is None else clearance[2],
            )
        )
    return summaries


def summarise_all(
    components: list[Component],
    limits: JointLimits,
    collision: CollisionCheck,
    reference_rad: FloatArray | None,
    max_configurations: int | None,
    include_paths: bool,
    deadline: Deadline = NO_DEADLINE,
    include_roadmap: bool = False,
) -> list[ComponentSummary]:
    """Summaries ordered by distance to the reference when given, else by size (largest first,
    then the longest path)."""
    if reference_rad is not None:
        reference_rad = limits.wrap(reference_rad)
    summaries = summarise(
        measured(components, collision), limits, reference_rad, max_configurations,
        include_paths, deadline, include_roadmap,
    )  # fmt: skip
    if reference_rad is not None:
        return sorted(summaries, key=lambda s: (s.distance_to_reference_rad, -s.size))
    return sorted(summaries, key=lambda s: (-s.size, -(s.arc_length_rad or 0.0)))
