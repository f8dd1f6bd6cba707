"""Stage 5: group accepted configurations into components on the joint metric.

Two configurations are linked when their joint-metric distance is at most the
clustering radius; components are the connected components of that graph
(single linkage), so every configuration lands in exactly one component and a
lone one is a component of size 1. Neighbours come from a KD-tree whose box is
toroidal only along periodic joints, so the graph is built in O(N log N) without
an N x N matrix.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from service.pipeline.joint_space import TWO_PI
from service.pipeline.types import BoolArray, FloatArray


def component_labels(
    q_rad: FloatArray,  # (N, n)
    periodic: BoolArray,  # (n,)
    radius_rad: float,
) -> NDArray[np.int64]:  # (N,) labels 0..K-1, largest component first
    """Connected components of the graph linking configurations within `radius_rad`."""
    num_points, _n = q_rad.shape
    if num_points == 0:
        return np.zeros(0, dtype=np.int64)
    # Shift every coordinate into [0, box): periodic joints onto [0, 2 pi) with a
    # toroidal box; limited joints into a box wide enough that no pair within the
    # radius can be linked across its edge.
    lowest = q_rad.min(axis=0)
    span = q_rad.max(axis=0) - lowest
    box = np.where(periodic, TWO_PI, span + 2.0 * radius_rad + 1.0)  # (n,)
    points = np.where(periodic, np.mod(q_rad, TWO_PI), q_rad - lowest)  # (N, n)
    points = np.where(points >= box, points - box, points)  # np.mod may round up to 2 pi
    tree = cKDTree(points, boxsize=box)
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
