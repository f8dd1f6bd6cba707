"""Stage 5 for any r: components as the connected parts of a roadmap on the fibre.

Nodes are the accepted configurations; an edge is kept only when the projected local
planner (local_planner.py) walks it on the fibre inside the limits. Candidate edges are
chosen so that few are checked: each node's nearest neighbours within a generous radius,
tested cheapest first in Boruvka rounds (each round, every component tries its shortest
untested edge to another component, so an edge inside an already joined component is
never paid for); then, between the components left, the few nearest pairs within a
wider radius are tried with a larger path-length allowance.

Where components are still apart and the chain has coaxial sets (coaxial.py: the
shoulder, elbow or wrist alignments where twin branches meet), nodes are added on those
sets: the samples of each component nearest a set are projected onto it (the aligning
joint held at its angle), and from each such point the exact straight self-motion of
the set is laid out as a line of nodes inside the limits, its consecutive valid nodes
joined (the line lies on the fibre; a node in collision joins nothing). The bridges
then run again over the enlarged roadmap.
Between the components still apart, walks steered along the fibre (steering.py: toward
a node of the other component in the tangent space, sliding along joint limits) start
from both ends of each pair's nearest links; where a walk ends, the planner tries the
edge to its goal and to the nearest node of any other component. This joins the thin
pieces the limits leave of a 4-D fibre, whose samples are far apart along a bent or
limit-bounded way that no straight edge follows.
Components are the connected components of the graph of walked edges; a lone node is a
component of its own. Each component keeps its graph (`ComponentRoadmap`): its samples,
then the nodes added to join them, each brought by Newton from the walks' projection
tolerance to the query's (`FibreSpace.polish`), and the edges between them. An added node
that the polish cannot make valid leaves the graph with its edges before the components
are read off it, so that every node of a component's graph is exact and its edges join
them all.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from service.pipeline import native
from service.pipeline.arrays import BoolArray, FloatArray, IntArray
from service.pipeline.connect.coaxial import slide_range
from service.pipeline.connect.local_planner import PlannerSettings, edges_on_fibre
from service.pipeline.connect.steering import SteerSettings, steer
from service.pipeline.deadline import NO_DEADLINE, Deadline
from service.pipeline.fibre import project
from service.pipeline.joint_space import JointBox, wrap_to_pi
from service.pipeline.space import FibreSpace
from service.pipeline.types import CoaxialSet, ComponentRoadmap


@dataclass(frozen=True)
class RoadmapSettings:
    neighbours: int  # candidate edges per node
    radius_rad: float  # longest candidate edge between neighbours
    bridge_radius_rad: float  # longest edge tried between components left apart
    bridge_pairs: int  # nearest pairs tried per pair of components
    bridge_lambda: float  # path-length allowance of a bridge edge, in chords
    # Nodes on coaxial sets: per component and set, this many samples nearest the set ...
    coaxial_nodes: int = 4
    coaxial_reach_rad: float = 0.6  # ... at most this far from it in the aligning joint,
    slide_step_rad: float = 0.3  # and the set's self-motion laid out at this spacing
    projection_iterations: int = 3  # Newton steps per step of a walk onto a set
    # Steering walks between the components still apart (steering.py): from both ends of
    # this many nearest links per pair of components, steps of steer_step_rad, at most
    # steer_max_steps of them (0 pairs: no steering).
    steer_pairs: int = 3
    steer_step_rad: float = 0.15
    steer_max_steps: int = 100
    steer_radius_rad: float = 6.0  # longest link between components that a walk follows


@dataclass(frozen=True)
class RoadmapComponents:
    """The samples' components and each component's graph."""

    labels: IntArray  # (K,) component of each sample, 0..C-1, largest component first
    graphs: list[ComponentRoadmap]  # (C,) by label: its samples in order, then added nodes


def roadmap_components(
    space: FibreSpace,
    q_rad: FloatArray,  # (K, n) valid configurations
    planner: PlannerSettings,
    settings: RoadmapSettings,
    deadline: Deadline = NO_DEADLINE,
) -> RoadmapComponents:
    """Components of q_rad joined by edges checked on the fibre, with their graphs."""
    num_samples = len(q_rad)
    if num_samples == 0:
        return RoadmapComponents(np.zeros(0, dtype=np.int64), [])
    roadmap = Roadmap(space, q_rad, planner, deadline)
    roadmap.join_neighbours(settings)
    roadmap.bridge(settings)
    apart = len(np.unique(roadmap.roots()[:num_samples])) > 1
    if apart and space.coaxial_sets and roadmap.add_coaxial_nodes(num_samples, settings):
        roadmap.bridge(settings)
    if len(np.unique(roadmap.roots()[:num_samples])) > 1:
        roadmap.steer_between(settings)
    return roadmap.finished(num_samples)


@dataclass
class Roadmap:
    """Nodes on the fibre and the edges the planner walked between them (append-only)."""

    space: FibreSpace  # where the nodes lie and the edges are walked
    q_rad: FloatArray  # (N, n)
    planner: PlannerSettings
    deadline: Deadline
    joined_from: list[IntArray] = field(default_factory=list)
    joined_to: list[IntArray] = field(default_factory=list)
    tested: set[int] = field(default_factory=set)  # a * N_max + b of every edge tried

    _KEY = 1 << 32

    _labels: IntArray | None = field(default=None, init=False, repr=False)  # roots() ...
    _applied: int = field(default=0, init=False, repr=False)  # ... after this many joins

    def roots(self) -> IntArray:  # (N,) the component of each node, from the edges so far
        """The connected components, numbered as `_components` numbers them (by their
        lowest node), updated from the edges joined since the last call: the components
        so far are merged along the new edges only (read-only; do not modify)."""
        num_nodes, edges = len(self.q_rad), len(self.joined_from)
        labels = self._labels
        if labels is not None and self._applied == edges and len(labels) == num_nodes:
            return labels
        if labels is None:
            labels = np.arange(num_nodes)
        else:  # nodes added since: each its own component until an edge joins it
            added = labels.max(initial=-1) + 1 + np.arange(num_nodes - len(labels))
            labels = np.append(labels, added)
        new_from = [labels[a] for a in self.joined_from[self._applied :]]
        new_to = [labels[b] for b in self.joined_to[self._applied :]]
        # The components of the components along the new edges, numbered by lowest node.
        self._labels = native.merge_labels(
            labels, np.concatenate([np.zeros(0, np.int64), *new_from]),
            np.concatenate([np.zeros(0, np.int64), *new_to]),
        )  # fmt: skip
        self._labels.flags.writeable = False
        self._applied = edges
        return self._labels

    def finished(self, num_samples: int) -> RoadmapComponents:
        """The components of the first `num_samples` nodes and their graphs, the added
        nodes polished to the query's tolerance (those it cannot make valid left out with
        their edges, and with them any added node no longer joined to a sample)."""
        q = self.q_rad.copy()
        kept = np.ones(len(q), dtype=bool)
        if len(q) > num_samples:
            q[num_samples:], kept[num_samples:] = self.space.polish(q[num_samples:])
        a = np.concatenate([np.zeros(0, dtype=np.int64), *self.joined_from])
        b = np.concatenate([np.zeros(0, dtype=np.int64), *self.joined_to])
        edge = kept[a] & kept[b] & (a != b)
        low, high = np.unique(np.stack([np.minimum(a, b), np.maximum(a, b)])[:, edge], axis=1)
        # The same graph as the edges so far when every node was kept.
        root = self.roots() if kept.all() else _components(len(q), [low], [high])
        labels = _ordered_labels(root[:num_samples])  # (K,)
        count = int(labels.max(initial=-1)) + 1
        label_of_root = np.full(int(root.max(initial=-1)) + 1, -1)
        label_of_root[root[:num_samples]] = labels
        node_label = np.where(kept, label_of_root[root], -1)  # (N,) -1: joined to no sample
        # Each component's nodes: its samples in order, then its added nodes in order.
        order = np.lexsort((np.arange(len(q)) >= num_samples, node_label))
        order = order[node_label[order] >= 0]  # (M,) grouped by component
        starts = np.searchsorted(node_label[order], np.arange(count + 1))  # (C + 1,)
        local = np.empty(len(q), dtype=np.int64)  # each node's index in its component
        local[order] = np.arange(len(order)) - starts[node_label[order]]
        edge_label = node_label[low]  # (E,) an edge joins two nodes of one component
        graphs = [
            ComponentRoadmap(
                q_rad=q[order[starts[c] : starts[c + 1]]],
                edges=np.stack([local[low[edge_label == c]], local[high[edge_label == c]]], axis=1),
            )
            for c in range(count)
        ]
        return RoadmapComponents(labels, graphs)

    def join(self, a: IntArray, b: IntArray) -> None:
        """Record edges known to lie on the fibre (not walked by the planner)."""
        self.joined_from.append(a)
        self.joined_to.append(b)

    def check(self, a: IntArray, b: IntArray, lambda_: float | None = None) -> None:
        """Walk the edges a-b with the planner and keep those that reach their end."""
        self.tested.update((np.minimum(a, b) * self._KEY + np.maximum(a, b)).tolist())
        q_a, q_b = self.q_rad[a], self.q_rad[b]
        joined = edges_on_fibre(self.space, q_a, q_b, self.planner, lambda_, self.deadline)
        self.join(a[joined], b[joined])

    def untested(self, a: IntArray, b: IntArray) -> BoolArray:
        keys = np.minimum(a, b) * self._KEY + np.maximum(a, b)
        if not self.tested:
            return np.ones(len(a), dtype=bool)
        return ~np.isin(keys, np.fromiter(self.tested, dtype=np.int64))

    def _box(self, settings: RoadmapSettings) -> JointBox:
        """KD-tree coordinates over every node, exact for neighbours up to a bridge apart."""
        margin_rad = 2.0 * max(settings.bridge_radius_rad, settings.steer_radius_rad) + 1.0
        return self.space.limits.box(self.q_rad, margin_rad=margin_rad)

    def _neighbours(
        self, k: int, radius_rad: float, settings: RoadmapSettings
    ) -> tuple[IntArray, ...]:
        """Every node's k nearest within radius: (rows, cols, lengths), flattened."""
        box = self._box(settings)
        points = box.points(self.q_rad)
        k = min(k, len(self.q_rad))
        distance, neighbour = box.tree(self.q_rad).query(
            points, k=k, distance_upper_bound=radius_rad
        )
        rows = np.repeat(np.arange(len(self.q_rad)), k)
        cols, length = neighbour.reshape(-1), distance.reshape(-1)
        keep = np.isfinite(length) & (cols < len(self.q_rad))
        return rows[keep], cols[keep], length[keep]

    def join_neighbours(self, settings: RoadmapSettings) -> None:
        """Boruvka rounds over the neighbour edges: each component's shortest untested one."""
        rows, cols, length = self._neighbours(
            settings.neighbours + 1, settings.radius_rad, settings
        )
        keep = rows < cols
        a, b, length = rows[keep], cols[keep], length[keep]
        order = np.argsort(length, kind="stable")
        a, b = a[order], b[order]
        untested = self.untested(a, b)
        while True:
            root = self.roots()
            open_ = untested & (root[a] != root[b])
            if not open_.any():
                break
            candidate = np.flatnonzero(open_)  # sorted by length
            # First (shortest) open edge of each component, from either end.
            from_a = _first_per(root[a[candidate]], candidate)
            from_b = _first_per(root[b[candidate]], candidate)
            chosen = np.unique(np.concatenate([from_a, from_b]))
            untested[chosen] = False
            self.check(a[chosen], b[chosen])

    def bridge(self, settings: RoadmapSettings) -> None:
        """Between the components left: the `bridge_pairs` nearest untested pairs of nodes
        of each pair of components, walked with the bridge's path-length allowance."""
        rows, cols = self._nearest_pairs(
            settings, settings.bridge_pairs, settings.bridge_radius_rad, untested_only=True
        )
        if len(rows):
            self.check(rows, cols, lambda_=settings.bridge_lambda)

    def _nearest_pairs(
        self, settings: RoadmapSettings, per_pair: int, radius_rad: float, untested_only: bool
    ) -> tuple[IntArray, IntArray]:  # (P,) node a, (P,) node b in another component
        """The `per_pair` shortest links within `radius_rad` of each pair of components.

        Every node outside a component of several nodes gets its nearest node in it, so
        each pair of components has links from the nodes of both sides (a lone node's side
        too); per pair the shortest distinct links are kept. A lone node is every other
        node's nearest in its component, so its links are all its neighbours within the
        radius. Both by brute force in compiled code over the KD-tree box's coordinates
        (`native.nearest_of_sets`, `native.links_within`): with the bridge's radius of
        several radians a KD-tree per component, each queried by every node, pruned little
        and cost 1 to 10 ms a call on an iiwa14 position answer's thousand nodes.
        """
        root = self.roots()
        labels, sizes = np.unique(root, return_counts=True)
        empty = np.zeros(0, dtype=np.int64)
        if len(labels) == 1 or per_pair == 0:
            return empty, empty
        box = self._box(settings)
        points = box.points(self.q_rad)
        # The tree's metric: periodic with the box in every dimension where a joint is.
        widths = box.box_rad if box.periodic.any() else np.full(points.shape[1], np.inf)
        rows_: list[IntArray] = []
        cols_: list[IntArray] = []
        length_: list[FloatArray] = []
        lone = np.flatnonzero(np.isin(root, labels[sizes == 1]))  # (L,) nodes
        if len(lone):
            i, j, v = native.links_within(points, widths, lone, radius_rad)
            rows_.append(lone[i])
            cols_.append(j)
            length_.append(v)
        several = labels[sizes > 1]  # (M,) in order
        if len(several):
            index = np.full(int(root.max()) + 1, -1)
            index[several] = np.arange(len(several))
            nearest, x, length = native.nearest_of_sets(
                points, widths, index[root], len(several), radius_rad, self.space.fibre.threads
            )  # each node's nearest of each component of several, by component then node
            rows_.append(nearest)
            cols_.append(x)
            length_.append(length)
        rows, cols = np.concatenate(rows_), np.concatenate(cols_)
        length = np.concatenate(length_)
        low, high = np.minimum(rows, cols), np.maximum(rows, cols)  # one link per node pair
        _, unique = np.unique(low * len(self.q_rad) + high, return_index=True)
        rows, cols, length = low[unique], high[unique], length[unique]
        if untested_only:
            keep = self.untested(rows, cols)
            rows, cols, length = rows[keep], cols[keep], length[keep]
        root_a, root_b = root[rows], root[cols]
        pair_key = np.minimum(root_a, root_b) * len(self.q_rad) + np.maximum(root_a, root_b)
        order = np.lexsort((length, pair_key))
        rank = np.arange(len(order)) - np.searchsorted(pair_key[order], pair_key[order])
        chosen = order[rank < per_pair]
        return rows[chosen], cols[chosen]

    def steer_between(self, settings: RoadmapSettings) -> None:
        """Walks on the fibre between the components left (steering.py), from both ends
        of each pair's nearest links; where a walk ends, the planner tries the edge to
        its goal and to the nearest node of any other component."""
        rows, cols = self._nearest_pairs(
            settings, settings.steer_pairs, settings.steer_radius_rad, untested_only=False
        )
        if not len(rows):
            return
        start = np.concatenate([rows, cols])  # (W,) walks both ways
        goal = np.concatenate([cols, rows])
        steering = SteerSettings(
            step_rad=settings.steer_step_rad,
            max_steps=settings.steer_max_steps,
            lambda_=self.planner.lambda_,
            projection_tolerance=self.planner.projection_tolerance,
            limit_check_rad=self.planner.limit_check_rad,
        )
        walk = steer(self.space, self.q_rad[start], self.q_rad[goal], steering, self.deadline)
        first = len(self.q_rad)
        end = np.arange(first, first + len(start))  # (W,) each walk's end, a new node
        self.q_rad = np.concatenate([self.q_rad, walk.q_end_rad])
        self.join(start, end)  # the walk is a path on the fibre
        root = self.roots()
        box = self._box(settings)
        k = min(8, len(self.q_rad))
        _, neighbour = box.tree(self.q_rad).query(
            box.points(walk.q_end_rad), k=k, distance_upper_bound=settings.bridge_radius_rad
        )  # (W, k)
        valid = neighbour < len(self.q_rad)
        other = valid & (root[np.where(valid, neighbour, 0)] != root[start][:, None])
        has_other = other.any(axis=1)
        nearest_other = neighbour[np.arange(len(start)), np.argmax(other, axis=1)]
        a = np.concatenate([end, end[has_other]])
        b = np.concatenate([goal, nearest_other[has_other]])
        other_than_goal = nearest_other[has_other] != goal[has_other]
        distinct = np.concatenate([np.ones(len(end), dtype=bool), other_than_goal])
        self.check(a[distinct], b[distinct], lambda_=settings.bridge_lambda)

    def add_coaxial_nodes(self, num_samples: int, settings: RoadmapSettings) -> bool:
        """Lines of nodes along each coaxial set's self-motion, reached from the samples
        of every component nearest the set; True when any were added."""
        root = self.roots()
        q = self.q_rad[:num_samples]
        lines: list[FloatArray] = []  # (L, n) each, laid out along a set
        origins: list[int] = []  # the sample each line was reached from ...
        on_line: list[int] = []  # ... and the line's node where it arrived (a = 0)
        next_node = len(self.q_rad)  # index of the first node of the next line
        limits = self.space.limits
        for coaxial_set in self.space.coaxial_sets:
            self.deadline.check("connect")
            j = coaxial_set.joint
            gap = q[:, j] - coaxial_set.angle_rad
            gap = np.abs(wrap_to_pi(gap) if limits.periodic[j] else gap)  # (K,)
            near = np.flatnonzero(gap <= settings.coaxial_reach_rad)
            if not len(near):
                continue
            # The coaxial_nodes nearest the set in each component.
            order = near[np.lexsort((gap[near], root[near]))]
            rank = np.arange(len(order)) - np.searchsorted(root[order], root[order])
            origin = order[rank < settings.coaxial_nodes]  # (O,)
            q_set, good = self._walk_onto_set(q[origin], coaxial_set, settings)
            origin, q_set = origin[good], q_set[good]
            low, high = slide_range(coaxial_set, q_set, limits)
            step = settings.slide_step_rad
            for o, point, a_low, a_high in zip(origin, q_set, low, high, strict=True):
                # a = 0 (the point itself) and steps of at most slide_step both ways.
                below = np.linspace(a_low, 0.0, int(np.ceil(-a_low / step)) + 1)
                above = np.linspace(0.0, a_high, int(np.ceil(a_high / step)) + 1)
                a = np.concatenate([below, above[1:]])  # (L,) increasing, holds 0
                origins.append(int(o))
                on_line.append(next_node + len(below) - 1)
                lines.append(point[None] + a[:, None] * coaxial_set.slide[None])
                next_node += len(a)
        if not lines:
            return False
        first = len(self.q_rad)
        nodes = np.concatenate(lines)  # (L, n) inside the limits
        valid = self.space.valid(nodes)  # (L,) and free, where collisions are checked
        index = first + np.cumsum(valid) - 1  # (L,) each valid node's index once added
        self.q_rad = np.concatenate([self.q_rad, nodes[valid]])
        ends = np.cumsum([len(line) for line in lines]) - 1  # (lines,) each line's last node
        # Consecutive valid nodes of one line are joined: the line lies on the fibre.
        along = np.flatnonzero(~np.isin(np.arange(len(nodes) - 1), ends) & valid[:-1] & valid[1:])
        self.join(index[along], index[along + 1])
        arrived = np.asarray(on_line) - first  # (O,) rows of `nodes`
        reached = valid[arrived]  # each sample walked onto its line's node
        self.join(np.asarray(origins)[reached], index[arrived[reached]])
        return bool(valid.any())

    def _walk_onto_set(
        self, q_rad: FloatArray, coaxial_set: CoaxialSet, settings: RoadmapSettings
    ) -> tuple[FloatArray, BoolArray]:  # (O, n) on the set, (O,) reached it
        """Walk each configuration (O, n) along the fibre onto the set: the aligning joint
        moved in steps of at most `slide_step_rad / 3` toward the set's angle and held
        there while Newton puts the others back on the fibre; a walk fails where a step
        does not converge, leaves the limits or jumps (moves farther than lambda x the
        step's own chord allows, as the local planner's steps)."""
        j = coaxial_set.joint
        start = q_rad[:, j]
        gap = coaxial_set.angle_rad - start
        if self.space.limits.periodic[j]:
            gap = wrap_to_pi(gap)
        step_rad = settings.slide_step_rad / 3.0
        steps = max(int(np.ceil(np.abs(gap).max() / step_rad)), 1)
        locked = np.zeros_like(q_rad, dtype=bool)
        locked[:, j] = True
        q = q_rad.copy()
        ok = np.ones(len(q), dtype=bool)
        for s in range(1, steps + 1):
            guess = q.copy()
            guess[:, j] = start + gap * s / steps
            walked = project(self.space.fibre, guess, settings.projection_iterations, locked=locked)
            moved = np.linalg.norm(walked.q_rad - q, axis=1)
            # A valid motion but for the coaxial crossings: the walk ends on a set.
            ok &= (
                (walked.error_norm <= self.planner.projection_tolerance)
                & self.space.valid(walked.q_rad)
                & (moved <= self.planner.lambda_ * max(np.abs(gap).max() / steps, step_rad))
            )
            q = np.where(ok[:, None], walked.q_rad, q)
        q[:, j] = coaxial_set.angle_rad
        return q, ok


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
