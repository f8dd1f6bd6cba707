"""components: ordering by reference or size, nearest member, a covering capped subset,
and every component's mean in one pass equal to its own."""

import numpy as np

from service.pipeline.collision.check import CollisionCheck
from service.pipeline.components import (
    farthest_point_subset,
    joint_mean,
    segment_joint_mean,
    summarise_all,
)
from service.pipeline.joint_space import JointLimits, joint_distance
from service.pipeline.types import Component

PERIODIC = np.array([True, True])
NONE = CollisionCheck.none()
LIMITS = JointLimits(np.full(2, -np.pi), np.full(2, np.pi), PERIODIC)  # only periodic is read


def component(q: np.ndarray) -> Component:
    return Component(
        q_rad=q, position_error_m=np.zeros(len(q)), orientation_error_rad=np.zeros(len(q))
    )


def arc(centre: float, count: int) -> np.ndarray:
    theta = np.linspace(-0.5, 0.5, count)
    return np.stack([centre + theta, np.zeros(count)], axis=1)


def test_ordered_by_size_without_reference_and_by_distance_with_one() -> None:
    small, large = component(arc(2.0, 10)), component(arc(-1.0, 30))
    by_size = summarise_all([small, large], LIMITS, NONE, None, None, include_paths=True)
    assert [s.size for s in by_size] == [30, 10]
    assert by_size[0].distance_to_reference_rad is None
    reference = np.array([2.2, 0.1])
    by_reference = summarise_all([large, small], LIMITS, NONE, reference, None, include_paths=True)
    assert [s.size for s in by_reference] == [10, 30]
    nearest = by_reference[0].nearest_to_reference_rad
    brute = small.q_rad[np.argmin(joint_distance(small.q_rad, reference, PERIODIC))]
    np.testing.assert_array_equal(nearest, brute)


def test_reference_is_wrapped_on_periodic_joints() -> None:
    near_seam = component(np.array([[3.1, 0.0], [3.0, 0.0]]))
    (summary,) = summarise_all(
        [near_seam], LIMITS, NONE, np.array([-3.1 + 2 * np.pi * 3, 0.0]), None, include_paths=True
    )
    assert summary.distance_to_reference_rad is not None
    assert summary.distance_to_reference_rad < 0.1


def test_capped_configurations_cover_the_component_and_size_counts_all() -> None:
    q = arc(0.0, 200)
    (summary,) = summarise_all([component(q)], LIMITS, NONE, None, 11, include_paths=True)
    assert summary.size == 200 and len(summary.configurations_rad) == 11
    gaps = [joint_distance(summary.configurations_rad, p, PERIODIC).min() for p in q]
    # 11 points on an arc of length 1 cover it within 0.05 at best; farthest-point
    # sampling is within twice the best covering radius.
    assert max(gaps) <= 0.1 + 1e-9
    subset = farthest_point_subset(q, LIMITS, 100, 3)
    np.testing.assert_allclose(sorted(subset[:, 0]), [-0.5, 0.0, 0.5], atol=1e-2)


def test_joint_mean_is_circular_on_periodic_joints() -> None:
    q = np.array([[3.1, 1.0], [-3.1, 2.0]])
    limits = JointLimits(np.full(2, -np.pi), np.full(2, np.pi), np.array([True, False]))
    mean = joint_mean(q, limits)
    assert abs(abs(mean[0]) - np.pi) < 1e-9 and mean[1] == 1.5


def test_the_mean_of_each_segment_is_its_joint_mean_bitwise() -> None:
    """Every component's mean in one pass over all rows equals `joint_mean` of its own rows,
    bitwise (the summaries of many components do not depend on being computed together),
    and numpy's plain and circular means to rounding."""
    rng = np.random.default_rng(3)
    limits = JointLimits(np.full(3, -np.pi), np.full(3, np.pi), np.array([True, False, True]))
    size = np.array([1, 7, 30, 2, 113])
    start = np.cumsum(size) - size
    q = rng.uniform(-np.pi, np.pi, (size.sum(), 3))
    means = segment_joint_mean(q, start, size, limits)
    for index, (first, count) in enumerate(zip(start, size, strict=True)):
        rows = q[first : first + count]
        np.testing.assert_array_equal(means[index], joint_mean(rows, limits))
        circular = np.arctan2(np.sin(rows).mean(axis=0), np.cos(rows).mean(axis=0))
        expected = np.where(limits.periodic, circular, rows.mean(axis=0))
        np.testing.assert_allclose(means[index], expected, rtol=0, atol=1e-14)
