"""A 1-D fibre swept by one parameter: its exact points at values of the parameter, linked
into curves (numpy, float64). The Panda's pose SMM sweeps joint 7 (references/panda.py);
the UR5's axis SMM sweeps the rotation psi about the tool axis (references/axis.py).

`swept` asks `solve` for the fibre's exact points at a grid of parameter values. Between
neighbouring values, points are linked one to one (mutual nearest on the wrapped joint
distance) when the counts agree, every link is at most `max_step_rad` long and each is
clearly the nearest (at most half the distance to any other candidate); otherwise the
interval is bisected, down to `min_width_rad`. An interval that narrow where the counts
still differ holds a fold: the curve turns back in the parameter and two points
coalesce, so the two left over on the side with more points are one curve and are
linked to each other (they are ~sqrt(width) apart). One where a link is still long is a
fast swing next to a singular set, filled with straight points. A parameter that turns
a full circle (psi) closes the sweep: its last slice is linked to its first.
`traced_paths` follows the links into paths and loops.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

TWO_PI = 2.0 * np.pi


def angle_gap(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """(..., n) q_b - q_a, each joint wrapped to (-pi, pi]: the unconstrained fibre lives
    on the torus, and a curve that crosses a wrap stays one."""
    return np.pi - np.mod(np.pi - (q_b - q_a), TWO_PI)


@dataclass
class Sweep:
    """Exact slices of the fibre at parameter values and the links between their points:
    nodes are (slice, row); each node has at most two links."""

    solve: Callable[[float], np.ndarray]  # parameter -> (k, n) exact points, in the chart
    chart: Callable[[np.ndarray], np.ndarray]  # (..., n) points -> the same in the chart
    parameter: list[float] = field(default_factory=list)
    slices: list[np.ndarray] = field(default_factory=list)  # each (k, n)
    links: list[tuple[int, int, int, int]] = field(default_factory=list)  # (a, row, b, row)
    fill: dict[tuple[int, int, int, int], np.ndarray] = field(default_factory=dict)

    def add(self, value: float) -> int:
        self.parameter.append(value)
        self.slices.append(self.solve(value))
        return len(self.slices) - 1


def swept(
    solve: Callable[[float], np.ndarray],
    chart: Callable[[np.ndarray], np.ndarray],
    grid: np.ndarray,  # (K,) increasing parameter values
    max_step_rad: float,
    min_width_rad: float,
    closed: bool = False,  # the grid's last value is its first turned a full circle
) -> Sweep:
    """The slices at `grid`, bisected where a link is not clear, linked (see the module)."""
    sweep = Sweep(solve, chart)
    values = [sweep.add(value) for value in grid]
    pending = list(itertools.pairwise(values))
    while pending:
        a, b = pending.pop()
        width = sweep.parameter[b] - sweep.parameter[a]
        if not link(sweep, a, b, max_step_rad, width < min_width_rad):
            middle = sweep.add(0.5 * (sweep.parameter[a] + sweep.parameter[b]))
            pending += [(a, middle), (middle, b)]
    if closed and len(values) > 1:  # the same exact points at both ends: link them
        link(sweep, values[-1], values[0], max_step_rad, forced=True)
    return sweep


def link(sweep: Sweep, a: int, b: int, max_step_rad: float, forced: bool) -> bool:
    """Link slice a's points to slice b's if that is unambiguous (or `forced`); False when
    the interval must be bisected."""
    q_a, q_b = sweep.slices[a], sweep.slices[b]
    gap = np.linalg.norm(angle_gap(q_a[:, None], q_b[None]), axis=-1)  # (ka, kb)
    if not forced:
        if len(q_a) != len(q_b):
            return False
        if not len(q_a):
            return True
        # Each point's nearest in the other slice, both ways the same, short, and clearly
        # nearer than any rival.
        cols = np.argmin(gap, axis=1)
        rows = np.arange(len(q_a))
        matched = gap[rows, cols]
        ranked = np.sort(gap, axis=1)[:, 1] if len(q_b) > 1 else np.full(len(q_a), np.inf)
        rival = np.sort(gap, axis=0)[1] if len(q_a) > 1 else np.full(len(q_b), np.inf)
        if (
            np.any(np.argmin(gap, axis=0)[cols] != rows)
            or np.any(matched > max_step_rad)
            or np.any(matched > 0.5 * np.minimum(ranked, rival[cols]))
        ):
            return False
        sweep.links += [
            (a, row, b, col) for row, col in zip(rows.tolist(), cols.tolist(), strict=True)
        ]
        return True
    rows, cols = linear_sum_assignment(gap)
    for row, col in zip(rows.tolist(), cols.tolist(), strict=True):
        add_link(sweep, (a, row, b, col), max_step_rad)
    # Forced with unequal counts: a fold. The points left over pair up nearest first.
    side, left = (a, np.setdiff1d(np.arange(len(q_a)), rows)) if len(q_a) > len(q_b) else (
        b, np.setdiff1d(np.arange(len(q_b)), cols))  # fmt: skip
    left_q = sweep.slices[side][left]
    while len(left) >= 2:
        distance = np.linalg.norm(angle_gap(left_q[0], left_q[1:]), axis=-1)
        partner = 1 + int(np.argmin(distance))
        add_link(sweep, (side, int(left[0]), side, int(left[partner])), max_step_rad)
        keep = np.ones(len(left), bool)
        keep[[0, partner]] = False
        left, left_q = left[keep], left_q[keep]
    return True


def add_link(sweep: Sweep, link: tuple[int, int, int, int], max_step_rad: float) -> None:
    """Record a link; one longer than `max_step_rad` gets straight points in between."""
    sweep.links.append(link)
    start = sweep.slices[link[0]][link[1]]
    step = angle_gap(start, sweep.slices[link[2]][link[3]])
    count = int(np.ceil(np.linalg.norm(step) / max_step_rad))
    if count > 1:
        fraction = np.arange(1, count)[:, None] / count
        sweep.fill[link] = sweep.chart(start + fraction * step)


def traced_paths(sweep: Sweep) -> list[tuple[np.ndarray, bool]]:
    """The linked points traced into paths (k, n) in order, each with whether it loops."""
    n = sweep.slices[0].shape[1] if sweep.slices else 0
    offset = np.cumsum([0] + [len(s) for s in sweep.slices])
    nodes = np.concatenate(sweep.slices) if offset[-1] else np.zeros((0, n))  # (N, n)
    neighbours: list[list[tuple[int, np.ndarray]]] = [[] for _ in range(len(nodes))]
    for joined in sweep.links:
        i, j = int(offset[joined[0]] + joined[1]), int(offset[joined[2]] + joined[3])
        between = sweep.fill.get(joined, np.zeros((0, n)))
        neighbours[i].append((j, between))
        neighbours[j].append((i, between[::-1]))
    seen = np.zeros(len(nodes), bool)
    paths: list[tuple[np.ndarray, bool]] = []
    for start in sorted(range(len(nodes)), key=lambda i: len(neighbours[i]) != 1):
        if not seen[start]:
            paths.append(_trace(start, nodes, neighbours, seen))
    return paths


def _trace(
    start: int,
    nodes: np.ndarray,
    neighbours: list[list[tuple[int, np.ndarray]]],
    seen: np.ndarray,
) -> tuple[np.ndarray, bool]:
    """(k, n) the points from `start` along its links in order, and whether they loop."""
    rows = [nodes[[start]]]
    seen[start] = True
    current, count = start, 1
    while True:
        ahead = [(n, between) for n, between in neighbours[current] if not seen[n]]
        if not ahead:
            # Back at the start through another link than the first one: a loop.
            closing = [between for n, between in neighbours[current] if n == start]
            if count >= 3 and closing:
                return np.concatenate([*rows, closing[0]]), True
            return np.concatenate(rows), False
        current, between = ahead[0]
        rows += [between, nodes[[current]]]
        seen[current] = True
        count += 1
