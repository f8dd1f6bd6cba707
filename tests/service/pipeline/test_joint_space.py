"""joint_space: angles wrap to (-pi, pi], only periodic joints are wrapped, and the KD-tree
box (JointBox) measures the same joint metric, exactly so with no periodic joint."""

import numpy as np
from scipy.spatial import cKDTree

from service.pipeline.joint_space import (
    JointBox,
    joint_difference,
    joint_distance,
    wrap_periodic,
    wrap_to_pi,
)


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
    limited = np.zeros(2, dtype=bool)  # no periodic joint: the plain difference, any size
    q_c = np.array([[7.5, -9.0], [0.1, 3.2]])
    np.testing.assert_array_equal(joint_difference(q_c, q_b, limited), q_c - q_b)
    np.testing.assert_allclose(joint_distance(q_c, q_b, limited), np.hypot(*(q_c - q_b).T))


def test_wrap_periodic_leaves_limited_joints_alone() -> None:
    q = np.array([[4.0, 4.0]])
    np.testing.assert_allclose(wrap_periodic(q, np.array([True, False])), [[4.0 - 2 * np.pi, 4.0]])


def test_joint_box_tree_finds_the_joint_metric_nearest_neighbour() -> None:
    """Brute force over the joint metric agrees with the KD-tree in JointBox coordinates,
    across the seam of a periodic joint and never across the +-pi of a limited one."""
    rng = np.random.default_rng(4)
    periodic = np.array([True, False, True])
    data = rng.uniform(-np.pi, np.pi, (300, 3))
    query = rng.uniform(-np.pi, np.pi, (50, 3))
    query[0] = [np.pi - 0.01, 3.1, 0.0]  # near the seam of joint 0, the edge of joint 1
    data[0] = [-np.pi + 0.01, -3.1, 0.0]  # 0.02 away on joint 0, 6.2 away on joint 1
    box = JointBox.covering(np.concatenate([query, data]), periodic, margin_rad=10.0)
    distance, index = box.tree(data).query(box.points(query))
    brute = joint_distance(query[:, None, :], data[None, :, :], periodic)  # (50, 300)
    np.testing.assert_allclose(distance, brute.min(axis=1), atol=1e-12)
    np.testing.assert_array_equal(index, brute.argmin(axis=1))


def test_joint_box_tree_without_periodic_joints_is_exact_beyond_the_margin() -> None:
    """With only limited joints the tree is a plain one: its k nearest and their distances
    are the joint metric's (brute force) even past the box's margin, where a wrapped box
    would bring far points closer across its edge; within the margin, the wrapped box
    (`boxsize`, what serves periodic chains) gives the same distances to the last bit."""
    rng = np.random.default_rng(5)
    periodic = np.zeros(7, dtype=bool)
    data = rng.uniform(-3.0, 3.0, (400, 7))
    query = rng.uniform(-3.0, 3.0, (60, 7))
    box = JointBox.covering(np.concatenate([query, data]), periodic, margin_rad=0.5)
    distance, index = box.tree(data).query(box.points(query), k=5)
    brute = joint_distance(query[:, None, :], data[None, :, :], periodic)  # (60, 400)
    np.testing.assert_array_equal(index, np.argsort(brute, axis=1)[:, :5])
    np.testing.assert_allclose(distance, np.sort(brute, axis=1)[:, :5], rtol=1e-14)
    wide = JointBox.covering(np.concatenate([query, data]), periodic, margin_rad=20.0)
    wrapped = cKDTree(wide.points(data), boxsize=wide.box_rad)
    near_w, index_w = wrapped.query(wide.points(query), k=5)
    near, index_p = wide.tree(data).query(wide.points(query), k=5)
    np.testing.assert_array_equal(index_p, index_w)
    np.testing.assert_array_equal(near, near_w)
