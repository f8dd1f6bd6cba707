"""clustering: components of the radius graph on the joint metric, seams handled per joint."""

import numpy as np
from scipy.sparse.csgraph import connected_components

from service.pipeline.clustering import component_labels
from service.pipeline.joint_space import joint_distance


def loop_across_seam(count: int = 400) -> np.ndarray:
    """A closed loop on T^3 whose first joint runs all the way round through +-pi."""
    theta = np.linspace(-np.pi, np.pi, count, endpoint=False)
    return np.stack([theta, 0.5 * np.sin(theta), 0.3 * np.cos(2 * theta)], axis=1)


def test_loop_crossing_the_seam_of_a_periodic_joint_is_one_component() -> None:
    labels = component_labels(loop_across_seam(), np.array([True, True, True]), radius_rad=0.1)
    assert set(labels.tolist()) == {0}


def test_clusters_across_the_seam_of_a_limited_joint_stay_apart() -> None:
    rng = np.random.default_rng(0)
    near_plus = np.column_stack([rng.normal(0, 0.01, 50), np.full(50, 3.0)])
    near_minus = np.column_stack([rng.normal(0, 0.01, 50), np.full(50, -3.0)])
    q = np.concatenate([near_plus, near_minus])
    limited = component_labels(q, np.array([True, False]), radius_rad=0.5)
    assert len(set(limited.tolist())) == 2
    assert len(set(limited[:50].tolist())) == 1 and len(set(limited[50:].tolist())) == 1
    # The same points on a periodic joint are 2 pi - 6 = 0.28 rad apart: one component.
    assert len(set(component_labels(q, np.array([True, True]), 0.5).tolist())) == 1


def test_matches_dense_single_linkage_on_random_points() -> None:
    rng = np.random.default_rng(1)
    periodic = np.array([True, False, True, False])
    q = rng.uniform(-np.pi, np.pi, (300, 4))
    radius = 0.9
    dense = joint_distance(q[:, None, :], q[None, :, :], periodic) <= radius
    _, reference = connected_components(dense, directed=False)
    labels = component_labels(q, periodic, radius)
    # Same partition: labels map one-to-one onto the reference labels.
    pairs = set(zip(labels.tolist(), reference.tolist(), strict=True))
    assert len(pairs) == len(set(labels.tolist())) == len(set(reference.tolist()))
    sizes = np.bincount(labels)
    assert np.all(np.diff(sizes) <= 0), "label 0 is the largest component"


def test_every_point_lands_in_exactly_one_component_and_lone_points_count() -> None:
    q = np.array([[0.0, 0.0], [0.05, 0.0], [2.0, 2.0]])
    labels = component_labels(q, np.array([False, False]), 0.1)
    assert labels.tolist() == [0, 0, 1]
    assert component_labels(np.zeros((0, 2)), np.array([False, False]), 0.1).shape == (0,)
