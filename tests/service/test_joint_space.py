"""joint_space: angles wrap to (-pi, pi] and only periodic joints are wrapped."""

import numpy as np

from service.pipeline.joint_space import joint_difference, joint_distance, wrap_periodic, wrap_to_pi


def test_wrap_to_pi_lands_in_half_open_interval_and_differs_by_whole_turns() -> None:
    angle = np.linspace(-20.0, 20.0, 4001)
    wrapped = wrap_to_pi(angle)
    assert np.all(wrapped > -np.pi) and np.all(wrapped <= np.pi)
    turns = (angle - wrapped) / (2 * np.pi)
    np.testing.assert_allclose(turns, np.round(turns), atol=1e-12)
    assert wrap_to_pi(np.array(np.pi)) == np.pi
    assert wrap_to_pi(np.array(-np.pi)) == np.pi


def test_difference_wraps_periodic_joints_only() -> None:
    periodic = np.array([True, False])
    q_a = np.array([3.0, 3.0])
    q_b = np.array([-3.0, -3.0])
    np.testing.assert_allclose(joint_difference(q_a, q_b, periodic), [6.0 - 2 * np.pi, 6.0])
    expected = np.hypot(2 * np.pi - 6.0, 6.0)
    np.testing.assert_allclose(joint_distance(q_a, q_b, periodic), expected)


def test_wrap_periodic_leaves_limited_joints_alone() -> None:
    q = np.array([[4.0, 4.0]])
    np.testing.assert_allclose(wrap_periodic(q, np.array([True, False])), [[4.0 - 2 * np.pi, 4.0]])
