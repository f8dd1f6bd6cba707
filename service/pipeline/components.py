"""Describe each component for the response: representative, bounds, errors, reference distance.

Every member counts in `size`; when the client caps the configurations returned per
component, the ones returned are chosen by farthest-point sampling so that they
still cover the whole component.
"""

from __future__ import annotations

import numpy as np

from service.pipeline.arrays import BoolArray, FloatArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.joint_space import joint_distance, wrap_to_pi
from service.pipeline.types import Component, ComponentSummary


def joint_mean(q_rad: FloatArray, periodic: BoolArray) -> FloatArray:
    """Mean (n,) of configurations (k, n): circular mean on periodic joints, plain elsewhere."""
    circular = np.arctan2(np.sin(q_rad).mean(axis=0), np.cos(q_rad).mean(axis=0))
    return np.where(periodic, circular, q_rad.mean(axis=0))


def farthest_point_subset(
    q_rad: FloatArray,
    periodic: BoolArray,
    start: int,
    count: int,
    deadline: Deadline = NO_DEADLINE,
) -> FloatArray:
    """`count` members (count, n) of q_rad (k, n), greedily each farthest from those chosen."""
    if count >= len(q_rad):
        return q_rad
    chosen = [start]
    distance = joint_distance(q_rad, q_rad[start], periodic)  # (k,)
    for _ in range(count - 1):
        deadline.check("cluster")
        nxt = int(np.argmax(distance))
        chosen.append(nxt)
        distance = np.minimum(distance, joint_distance(q_rad, q_rad[nxt], periodic))
    return q_rad[np.asarray(chosen)]


def summarise(
    component: Component,
    periodic: BoolArray,
    reference_rad: FloatArray | None,
    max_configurations: int | None,
    deadline: Deadline = NO_DEADLINE,
) -> ComponentSummary:
    q = component.q_rad  # (k, n)
    centre = joint_mean(q, periodic)
    representative = int(np.argmin(joint_distance(q, centre, periodic)))
    configurations = (
        q
        if max_configurations is None
        else farthest_point_subset(q, periodic, representative, max_configurations, deadline)
    )
    distance_to_reference = None
    nearest = None
    if reference_rad is not None:
        distances = joint_distance(q, reference_rad, periodic)  # (k,)
        best = int(np.argmin(distances))
        distance_to_reference = float(distances[best])
        nearest = q[best]
    return ComponentSummary(
        size=len(q),
        representative_rad=q[representative],
        configurations_rad=configurations,
        joint_min_rad=q.min(axis=0),
        joint_max_rad=q.max(axis=0),
        max_position_error_m=float(component.position_error_m.max()),
        max_orientation_error_rad=float(component.orientation_error_rad.max()),
        distance_to_reference_rad=distance_to_reference,
        nearest_to_reference_rad=nearest,
    )


def summarise_all(
    components: list[Component],
    periodic: BoolArray,
    reference_rad: FloatArray | None,
    max_configurations: int | None,
    deadline: Deadline = NO_DEADLINE,
) -> list[ComponentSummary]:
    """Summaries ordered by distance to the reference when given, else by size (largest first)."""
    if reference_rad is not None:
        reference_rad = np.where(periodic, wrap_to_pi(reference_rad), reference_rad)
    summaries = [
        summarise(c, periodic, reference_rad, max_configurations, deadline) for c in components
    ]
    if reference_rad is not None:
        return sorted(summaries, key=lambda s: (s.distance_to_reference_rad, -s.size))
    return sorted(summaries, key=lambda s: -s.size)
