"""Stage 5 for any r: components as the connected parts of a roadmap on the fibre.

Nodes are the accepted configurations; an edge is kept only when the projected local
planner (local_planner.py) walks it on the fibre inside the limits. Candidate edges are
chosen so that few are checked: each node's nearest neighbours within a generous radius,
tested cheapest first in Boruvka rounds (each round, every component tries its shortest
untested edge to another component, so an edge inside an already joined component is
never paid for); then, between the components left, the few nearest pairs within a
wider radius are tried with a larger path-length allowance. Components are the
connected components of the graph of walked edges; a lone node is a component of its own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import Fibre
from service.pipeline.joint_space import JointBox
from service.pipeline.local_planner import PlannerSettings, edges_on_fibre


@dataclass(frozen=True)
class RoadmapSettings:
    neighbours: int  # candidate edges per node
    radius_rad: float  # longest candidate edge between neighbours
    bridge_radius_rad: float  # longest edge tried between components left apart
    bridge_pairs: int  # nearest pairs tried per pair of components
    bridge_lambda: float  # path-length allowance of a bridge edge, in chords


def roadmap_labels(
    fibre: Fibre,
    q_rad: FloatArray,  # (K, n) on the fibre, inside the limits
    lower_rad: FloatArray,
    upper_rad: FloatArray,
    periodic: BoolArray,
    planner: PlannerSettings,
    settings: RoadmapSettings,
    deadline: Deadline = NO_DEADLINE,
) -> IntArray:  # (K,) component labels 0..C-1, largest component first
    """Components of q_rad joined by edges checked on the fibre."""
    num_nodes = len(q_rad)
    if num_nodes == 0:
        return np.zeros(0, dtype=np.int64)
    joined_from: list[IntArray] = []  # the edges the planner walked, both ends
    joined_to: list[IntArray] = []
    box = JointBox.covering(q_rad, periodic, margin_rad=2.0 * settings.bridge_radius_rad + 1.0)
    tree = box.tree(q_rad)
    points = box.points(q_rad)

    def check(a: IntArray, b: IntArray, lambda_: float | None = None) -> None:
        joined = edges_on_fibre(
            fibre, q_rad[a], q_rad[b], lower_rad, upper_rad, periodic, planner,
            lambda_=lambda_, deadline=deadline,
        )  # fmt: skip
        joined_from.append(a[joined])
        joined_to.append(b[joined])

    def roots() -> IntArray:  # (K,) the component of each node, from the edges so far
        return _components(num_nodes, joined_from, joined_to)

    # Neighbour edges, Boruvka rounds: each component's shortest untested outgoing edge.
    k = min(settings.neighbours + 1, num_nodes)
    distance, neighbour = tree.query(points, k=k, distance_upper_bound=settings.radius_rad)
    rows = np.repeat(np.arange(num_nodes), k)
    cols, length = neighbour.ravel(), distance.ravel()
    keep = np.isfinite(length) & (cols < num_nodes) & (rows < cols)
    a, b, length = rows[keep], cols[keep], length[keep]
    order = np.argsort(length, kind="stable")
    a, b, length = a[order], b[order], length[order]
    untested = np.ones(len(a), dtype=bool)
    while True:
        root = roots()
        open_ = untested & (root[a] != root[b])
        if not open_.any():
            break
        candidate = np.flatnonzero(open_)  # sorted by length
        # First (shortest) open edge of each component, from either end.
        chosen = np.unique(
            np.concatenate([_first_per(root[a[candidate]], candidate),
                            _first_per(root[b[candidate]], candidate)])
        )  # fmt: skip
        untested[chosen] = False
        check(a[chosen], b[chosen])

    # Bridges between the components left: the nearest pairs of each pair of components.
    root = roots()
    if len(np.unique(root)) > 1 and settings.bridge_pairs > 0:
        k = min(32, num_nodes)
        distance, neighbour = tree.query(
            points, k=k, distance_upper_bound=settings.bridge_radius_rad
        )
        rows = np.repeat(np.arange(num_nodes), k)
        cols, length = neighbour.ravel(), distance.ravel()
        keep = np.isfinite(length) & (cols < num_nodes)
        rows, cols, length = rows[keep], cols[keep], length[keep]
        keep = root[rows] < root[cols]
        rows, cols, length = rows[keep], cols[keep], length[keep]
        pair_key = root[rows] * num_nodes + root[cols]
        order = np.lexsort((length, pair_key))
        rank = np.arange(len(order)) - np.searchsorted(pair_key[order], pair_key[order])
        chosen = order[rank < settings.bridge_pairs]
        check(rows[chosen], cols[chosen], lambda_=settings.bridge_lambda)

    return _ordered_labels(roots())


def _components(num_nodes: int, starts: list[IntArray], ends: list[IntArray]) -> IntArray:
    """(K,) connected-component label of each node of the graph with these edges."""
    a = np.concatenate([np.zeros(0, dtype=np.int64), *starts])
    b = np.concatenate([np.zeros(0, dtype=np.int64), *ends])
    graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(num_nodes, num_nodes))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def _first_per(group: IntArray, index: IntArray) -> IntArray:
    """The first entry of `index` for each distinct value of `group` (same length)."""
    _, first = np.unique(group, return_index=True)
    return index[first]


def _ordered_labels(root: IntArray) -> IntArray:
    """Labels 0..C-1 with 0 the largest set (ties: the set holding the lowest index)."""
    _, labels = np.unique(root, return_inverse=True)
    sizes = np.bincount(labels)
    first = np.full(len(sizes), len(root))
    np.minimum.at(first, labels, np.arange(len(root)))
    order = np.lexsort((first, -sizes))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[labels].astype(np.int64)
