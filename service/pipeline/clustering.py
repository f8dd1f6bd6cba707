"""Stage 5: group the accepted configurations into components on the joint metric.

Two configurations are linked when their joint-metric distance is at most the
clustering radius; components are the connected components of that graph
(single linkage), so every configuration lands in exactly one component and a
lone one is a component of size 1. Neighbours come from a KD-tree whose box is
toroidal only along periodic joints, so the graph is built in O(N log N) without
an N x N matrix.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.joint_space import JointBox
from service.pipeline.types import Component, Correction


def group_components(
    correction: Correction,
    accepted: BoolArray,  # (N,)
    periodic: BoolArray,  # (n,)
    radius_rad: float,
    deadline: Deadline = NO_DEADLINE,
) -> list[Component]:
    """The accepted samples grouped into components, largest first; each accepted sample
    is in exactly one."""
    deadline.check("cluster")
    kept = np.flatnonzero(accepted)  # (K,) sample indices
    labels = component_labels(
        q_rad=correction.q_rad[kept], periodic=periodic, radius_rad=radius_rad
    )
    return [
        Component(
            q_rad=correction.q_rad[members],
            position_error_m=correction.position_error_m[members],
            orientation_error_rad=correction.orientation_error_rad[members],
        )
        for members in (kept[labels == label] for label in range(labels.max(initial=-1) + 1))
    ]


def component_labels(
    q_rad: FloatArray,  # (N, n)
    periodic: BoolArray,  # (n,)
    radius_rad: float,
) -> IntArray:  # (N,) labels 0..K-1, largest component first
    """Connected components of the graph linking configurations within `radius_rad`."""
    num_points, _n = q_rad.shape
    if num_points == 0:
        return np.zeros(0, dtype=np.int64)
    # Any margin over the radius keeps pairs from linking across a limited joint's box edge.
    tree = JointBox.covering(q_rad, periodic, margin_rad=2.0 * radius_rad + 1.0).tree(q_rad)
    pairs = tree.query_pairs(radius_rad, output_type="ndarray")  # (P, 2)
    graph = coo_matrix(
        (np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])),
        shape=(num_points, num_points),
    )
    _, labels = connected_components(graph, directed=False)
    # Relabel so that label 0 is the largest component (ties: first member's index).
    sizes = np.bincount(labels)
    first = np.full(len(sizes), num_points)
    np.minimum.at(first, labels, np.arange(num_points))
    order = np.lexsort((first, -sizes))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[labels].astype(np.int64)
