"""The free pieces of a position target's 4-D fibre (iiwa14), at the reference grid's
resolution, for the same recall and merges as the pose's (pieces.py).

The kinematic reference (`references.iiwa14.position_graph`: the closed-form IK on a grid
of end-effector directions and arm angles, every branch, with its links and the singular
sets' exact points) is taken at GRID_STEPS, times Q7_LAYERS values of q7 spread over its
range: q7 does not move the end effector, and it turns only link 7, whose geometry is
round about joint 7's axis to within 1.5 mm, so a few layers sample it. Each node of each
layer is a configuration; it is free when coal finds it free by the margin. The service's
check decides first what it can: what it calls free is free (it is conservative: the
exactness section checks that on every configuration it returns or calls free, and
every configuration coal decides here is one the check did not call free). Free pieces
are the components of the free nodes, linked along the reference's links within a layer
and between neighbouring layers at the same node; a piece's share is its nodes' area
weight over the whole fibre's (free or not, every layer). A piece's kinematic component
is the reference's component of its nodes.

A returned configuration lies on the piece of the nearest free grid node of its nearest
layer, in q1..q6, when that node is within MATCH_RAD (about the grid's node spacing at
GRID_STEPS, where the IK's gain is ordinary).

The grid bounds the measure: two free nodes linked are taken as joined, and a free
passage between two nodes' neighbourhoods narrower than a grid step is not seen, so the
grid can split one free piece in two. A returned component on both (joined by the
service's roadmap, whose every walk step is checked) then reads as a merge across a
cut. `position_recall` measures such a target again on finer grids (FINER_GRID_STEPS),
while a merge remains, and keeps the finest measure.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from service.models.registry import ServedModel
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.collision.scene import Obstacle
from training.evaluate.references.iiwa14 import position_graph
from training.evaluate.scenes.coal_model import CoalModel
from training.evaluate.scenes.pieces import FreePieces, Recall, recall

# The robots whose position reference has a graph to cut (references.iiwa14).
POSITION_REFERENCES = ("iiwa14",)
GRID_STEPS = 32
# Where the grid at GRID_STEPS finds a merge, it is measured again at these, in turn,
# while a merge remains: a passage narrower than a grid step is one the grid cannot see.
FINER_GRID_STEPS = (48, 64, 80)
Q7_LAYERS = 3
MATCH_RAD = 0.5


@dataclass(frozen=True)
class FreeRegions(FreePieces):
    """FreePieces of a 4-D fibre: `length_rad` holds each piece's share of the fibre
    (`fibre_length_rad` is 1), and a configuration is matched within its q7 layer."""

    layer: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # (P,)
    q7_layers_rad: FloatArray = field(default_factory=lambda: np.zeros(0))  # (L,)

    def pieces_of(self, q_rad: FloatArray, periodic: BoolArray) -> IntArray:  # (K,)
        """The piece of the nearest free node of each configuration's nearest layer."""
        on = np.full(len(q_rad), -1)
        if not len(q_rad):
            return on
        nearest_layer = np.abs(q_rad[:, 6:7] - self.q7_layers_rad[None]).argmin(axis=1)
        for layer in range(len(self.q7_layers_rad)):
            rows = np.flatnonzero(nearest_layer == layer)
            nodes = np.flatnonzero((self.layer == layer) & (self.label >= 0))
            if not len(rows) or not len(nodes):
                continue
            distance, nearest = cKDTree(self.q_rad[nodes, :6]).query(q_rad[rows, :6])
            on[rows] = np.where(distance <= MATCH_RAD, self.label[nodes[nearest]], -1)
        return on


def free_regions_of_position(
    model: ServedModel,
    coal: CoalModel,
    check_free: Callable[[FloatArray], BoolArray],  # the service's check
    q_target_rad: FloatArray,
    obstacles: Sequence[Obstacle],
    margin_m: float,
    grid_steps: int = GRID_STEPS,
    q7_layers: int = Q7_LAYERS,
) -> tuple[FreeRegions, BoolArray]:
    """The free pieces of the fibre of the position q_target reaches (module docstring),
    and the check's verdict on every reference point."""
    position = model.kinematics(q_target_rad[None]).position_m[0]
    graph = position_graph(position, grid_steps)
    nodes = len(graph.q6_rad)
    real = np.all(np.isfinite(graph.q6_rad), axis=1)
    real[: graph.grid.feasible.size] &= graph.grid.feasible.ravel()  # grid nodes in limits
    limit = float(model.limits.upper_rad[6])
    layers = np.linspace(-limit, limit, q7_layers + 2)[1:-1]  # inside the range, spread
    kinematic = graph.components(real)  # (N,)
    q = np.concatenate(
        [np.c_[graph.q6_rad[real], np.full(int(real.sum()), q7)] for q7 in layers]
    )  # (L * R, 7)
    checked = np.asarray(check_free(q), dtype=bool)
    free = checked.copy()
    undecided = np.flatnonzero(~free)
    free[undecided] = coal.free(q[undecided], obstacles, margin_m)
    # Node numbers over the layers: layer l's node i is l * N + i.
    index = (np.arange(q7_layers)[:, None] * nodes + np.flatnonzero(real)[None]).ravel()
    free_all = np.zeros(q7_layers * nodes, dtype=bool)
    free_all[index] = free
    within = (graph.link_from[None] + nodes * np.arange(q7_layers)[:, None]).ravel()
    to = (graph.link_to[None] + nodes * np.arange(q7_layers)[:, None]).ravel()
    across = (np.arange(q7_layers - 1)[:, None] * nodes + np.arange(nodes)[None]).ravel()
    link_from = np.concatenate([within, across])
    link_to = np.concatenate([to, across + nodes])
    label = _components(free_all, link_from, link_to)[index]  # (L * R,) -1: in collision
    # Set points only join grid nodes: a piece is its grid nodes, numbered 0..P-1.
    grid_node = np.tile(np.flatnonzero(real) < graph.grid.feasible.size, q7_layers)
    label = np.where(grid_node, label, -1)
    pieces, label_on = np.unique(label[label >= 0], return_inverse=True)
    label[label >= 0] = label_on
    on = label >= 0
    weight = np.tile(graph.weight[real], q7_layers)
    piece_weight = np.bincount(label[on], weights=weight[on], minlength=len(pieces))
    share: FloatArray = np.asarray(piece_weight / max(float(weight.sum()), 1e-300), np.float64)
    curve = np.zeros(len(pieces), dtype=np.int64)
    curve[label[on]] = np.tile(kinematic[real], q7_layers)[on]
    regions = FreeRegions(
        q_rad=q,
        label=label,
        length_rad=share,
        curve=curve,
        fibre_length_rad=1.0,
        layer=np.repeat(np.arange(q7_layers), int(real.sum())),
        q7_layers_rad=layers,
    )
    return regions, checked


def _components(kept: BoolArray, link_from: IntArray, link_to: IntArray) -> IntArray:
    """Component of each kept node over the links between kept nodes; -1 elsewhere."""
    both = kept[link_from] & kept[link_to]
    graph = coo_matrix(
        (np.ones(int(both.sum())), (link_from[both], link_to[both])),
        shape=(len(kept), len(kept)),
    )
    label = np.asarray(connected_components(graph, directed=False)[1])
    return np.where(kept, label, -1)


def position_recall(
    model: ServedModel,
    coal: CoalModel,
    check_free: Callable[[FloatArray], BoolArray],
    q_target_rad: FloatArray,
    obstacles: Sequence[Obstacle],
    margin_m: float,
    returned: FloatArray,  # (K, 7) every returned configuration
    labels: IntArray,  # (K,) its component
    kinematic: FloatArray,  # (J, 7) returned with nothing checked
) -> tuple[Recall, int]:
    """The pieces found and the merges at GRID_STEPS, or at the first of FINER_GRID_STEPS
    where no merge remains (the last when one does), and that grid's steps."""
    for steps in (GRID_STEPS, *FINER_GRID_STEPS):
        regions, checked = free_regions_of_position(
            model, coal, check_free, q_target_rad, obstacles, margin_m, steps
        )
        found = recall(regions, checked, returned, labels, model.limits.periodic, kinematic)
        if not found.merges:
            break
    return found, steps
